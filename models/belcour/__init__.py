"""belcour"""
