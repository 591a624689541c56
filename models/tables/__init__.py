"""Precomputed tables of the analytic models, computed by our own quadratures: the FGD and TIR
tables of Belcour's model and its material slices (:mod:`models.tables.belcour`), the
mean-transmission / mean-refraction tables of ``multilayer-lut`` (:mod:`models.tables.multilayer`),
the directional-albedo tables of one GGX interface of ``ggx-kulla-conty``
(:mod:`models.tables.microfacet_albedo`, ``docs/production-models.md``),
their cache files (:mod:`models.tables.cache`) and the build-and-check of ``gonio tables``
(:mod:`models.tables.check`). Definitions, grids, numerics and stated error bounds:
``docs/tables.md``.
"""

from models.tables.belcour import (FGD_ERROR, TIR_ERROR, BelcourTables, TableSlice, build_belcour_tables,
                                   fgd_direct, fgd_direct_many, fgd_slice, fgd_slice_from_table, load_belcour_tables, slice_lookup,
                                   stacked_slice_lookup, tir_direct, tir_slice, tir_slice_from_table)
from models.tables.cache import cache_directory, default_cache_dir
from models.tables.check import MASKINGS, Check, TableEntry, check_tables
from models.tables.multilayer import MultilayerTables, build_multilayer_tables, load_multilayer_tables
from models.tables.microfacet_albedo import AlbedoTable, fresnel_average, load_albedo_table

__all__ = [
    # Belcour FGD / TIR
    "BelcourTables", "load_belcour_tables", "build_belcour_tables", "TableSlice", "fgd_slice",
    "tir_slice", "fgd_slice_from_table", "tir_slice_from_table", "slice_lookup", "stacked_slice_lookup",
    "fgd_direct", "fgd_direct_many", "tir_direct", "FGD_ERROR", "TIR_ERROR",
    # multilayer-lut
    "MultilayerTables", "load_multilayer_tables", "build_multilayer_tables",
    # directional albedo of one GGX interface (ggx-kulla-conty)
    "AlbedoTable", "load_albedo_table", "fresnel_average",
    # files and checks
    "cache_directory", "default_cache_dir", "MASKINGS", "Check", "TableEntry", "check_tables",
]
