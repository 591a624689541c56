"""The tables renderers ship, computed by the simulator with a standard error per cell
(``gonio lut``; ``docs/lut.md``).

* :mod:`~models.lut.definition`: a table definition (quantity, grid, parametrization, rays) and
  its validation;
* :mod:`~models.lut.quantities`: the cells as simulator runs and the estimators that reduce them
  (the furnace's albedo, the production study's darkening and roughness);
* :mod:`~models.lut.compute`: rays (given, or from a pilot for a target standard error), runs
  with per-cell checkpoints, the table;
* :mod:`~models.lut.check`: the checks (quadrature, Fresnel at alpha -> 0, energy conservation,
  a published table, OpenPBR's coat formulas scored);
* :mod:`~models.lut.writers`: ``.npy``, JSON, the C header and the 16-bit PNG.
"""

from models.lut.check import (P_FALSE_ALARM, Z_TOL, CellCheck, check_table, compare_published, read_c_array,
                              reference_values, score_darkening, score_roughness)
from models.lut.compute import LutResult, Plan, Runner, compute_table, pilot, plan_table, rays_for_target, run_table
from models.lut.definition import (MAPS, QUANTITIES, Axis, Definition, LutError, Published, definition_from_dict,
                                   load_definition)
from models.lut.writers import c_array, header_text, png16, write_table

__all__ = [
    "MAPS", "QUANTITIES", "Axis", "Definition", "LutError", "Published", "definition_from_dict", "load_definition",
    "LutResult", "Plan", "Runner", "compute_table", "pilot", "plan_table", "rays_for_target", "run_table",
    "P_FALSE_ALARM", "Z_TOL", "CellCheck", "check_table", "compare_published", "read_c_array", "reference_values",
    "score_darkening", "score_roughness",
    "c_array", "header_text", "png16", "write_table",
]
