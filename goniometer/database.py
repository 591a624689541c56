"""Material databases: definition files that expand to many named materials, and resumable,
optionally distributed, simulation of all of them into one HDF5 file per material.

The definition format and the results directory are contracts of ``docs/database-format.md``::

    <out>/database.json                 manifest: database name, fingerprint, quality, format version
    <out>/<name>.h5                     one slices file per finished material (atomic writes; names
                                        are "<category>/<material>", hence a folder per category)
    <out>/.partial/<name>/m<k>.npz      checkpoints of finished incident directions of an
                                        unfinished material (removed when it is written)

A rerun skips finished materials, resumes unfinished ones from their checkpoints, and refuses a
directory that holds another database, quality or format (nothing is overwritten); checkpoints that
a material's run cannot use (another run, another version of the simulator code) are refused too,
never discarded unless asked (``restart``). A finished
file that cannot be read is reported and re-simulated only on request. A definition may ask for
spectral runs (``[simulation] spectral = true``, ``wavelength_bins``; ``docs/spectral.md``):
every material is then traced in wavelength bins, locally or on a Dask cluster.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import hashlib
import itertools
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from goniometer import atomic
from goniometer.files import slices as store
from goniometer.run.checkpoints import CheckpointMismatch, Checkpoints
from goniometer.run.results import run_description, same_run
from goniometer.run.settings import DEFAULT_INCIDENT, SettingsError, SimulationSettings
from goniometer.run.loop import run_incidents
from goniometer.stack import SIMULATION_KEYS as STACK_SIMULATION_KEYS
from goniometer.stack import Interface, Stack, StackError, stack_from_dict
from goniometer.kernel.packing import check_films
from goniometer.tomlfile import read_toml

MANIFEST = "database.json"
RESULTS_FORMAT = "goniometer.database-results"
RESULTS_VERSION = 1
PARAMS_REPORTED = ("alpha0", "alpha1", "tau", "rho", "eta1", "d", "g")
#: the keys of a definition's ``[simulation]`` table (``docs/database-format.md`` section 1.2): a material
#: file's (:data:`goniometer.stack.SIMULATION_KEYS`) but those a database sets itself (rays per quality,
#: the RGL grid made from each stack) or leaves to the command line (threads)
SIMULATION_KEYS = tuple(sorted(STACK_SIMULATION_KEYS - {"rays", "max_order", "threads", "first_order", "rgl_grid"}))
#: the bins of a spectral database that does not give ``wavelength_bins``: SimulationSettings' default
DEFAULT_WAVELENGTH_BINS = SimulationSettings.wavelength_bins
#: the parametrizations a database's materials can use (``rgl`` needs a grid made from each stack)
DATABASE_PARAMETRIZATIONS = ("classic", "half")
#: the parametrization rule's form (``docs/database-format.md`` section 1.2)
PARAMETRIZATION_RULE = '{ classic_if_alpha0_at_least = a, otherwise = "half" }'


class DatabaseError(ValueError):
    """An invalid database file or results directory (message names the file and the problem)."""


@dataclass(frozen=True)
class Material:
    """One expanded material: its stack, the paper's short name and its parameters."""

    name: str
    category: str
    paper_name: str
    stack: Stack
    params: dict[str, Any]
    parametrization: str


@dataclass(frozen=True)
class Database:
    """An expanded database definition (``docs/database-format.md`` section 1). ``spectral`` and
    ``wavelength_bins``: every material is traced spectrally in that many bins
    (``docs/spectral.md``); ``wavelength_bins`` other than the default goes with ``spectral``."""

    name: str
    path: str
    incident_deg: tuple[float, ...]
    resolution: tuple[int, int]
    seed: int
    masking: str
    qualities: dict[str, int]
    materials: tuple[Material, ...]
    description: str = ""
    spectral: bool = False
    wavelength_bins: int = DEFAULT_WAVELENGTH_BINS
    #: every material traced with polarized light (``docs/polarization.md``; ``[simulation] polarized``
    #: or ``gonio database simulate --polarized``)
    polarized: bool = False

    def __post_init__(self) -> None:
        if self.spectral is False and self.wavelength_bins != DEFAULT_WAVELENGTH_BINS:
            raise DatabaseError(_bins_without_spectral(self.path))

    def settings_for(self, material: Material, quality: str, threads: int | None = None) -> SimulationSettings:
        """The settings of ``material``'s run at ``quality`` (SettingsError for invalid ones)."""
        return self._settings(material.parametrization, quality, threads)

    def _settings(self, parametrization: str, quality: str, threads: int | None = None) -> SimulationSettings:
        if quality not in self.qualities:
            raise DatabaseError(f"{self.path}: quality {quality!r} is not one of {', '.join(self.qualities)}")
        return SimulationSettings(incident_deg=self.incident_deg, rays=self.qualities[quality],
                                  parametrization=parametrization, resolution=self.resolution,
                                  seed=self.seed, masking=self.masking, threads=threads,
                                  spectral=self.spectral, wavelength_bins=self.wavelength_bins,
                                  polarized=self.polarized)

    def fingerprint(self) -> str:
        """Hash of everything that determines the results (names, stacks, settings;
        ``docs/database-format.md`` section 2.2). The spectral keys enter only a spectral
        database's hash: an RGB database keeps the fingerprint it had before they existed."""
        doc = {"name": self.name, "incident": self.incident_deg, "resolution": self.resolution, "seed": self.seed,
               "masking": self.masking,
               "materials": [[m.name, m.stack.to_json(), m.parametrization] for m in self.materials]}
        if self.spectral:
            doc["spectral"] = True
            doc["wavelength_bins"] = self.wavelength_bins
        if self.polarized:   # (a scalar database keeps its fingerprint)
            doc["polarized"] = True
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]

    def select(self, only: str | None) -> list[Material]:
        """Materials whose name matches the glob ``only`` (all if None)."""
        if not only:
            return list(self.materials)
        chosen = [m for m in self.materials if fnmatch.fnmatchcase(m.name, only)]
        if not chosen:
            raise DatabaseError(f"--only {only!r} matches no material of {self.name}")
        return chosen


def _bins_without_spectral(path: str | Path) -> str:
    return (f"{path}: simulation: wavelength_bins: goes with spectral = true (the bins of a spectral run; an RGB "
            f"run has none)")


# ---------------------------------------------------------------------- loading

def load_database(path: str | Path) -> Database:
    """Load and expand a database definition; raises :class:`DatabaseError`."""
    p = Path(path)
    data = _read_definition(p)
    if "base" in data:
        base = data["base"]
        if not isinstance(base, str) or not base:
            raise DatabaseError(f"{p}: base: {base!r} is not a path (a string, relative to this file)")
        if not isinstance(data.get("name"), str) or not data.get("name"):
            raise DatabaseError(f"{p}: name: required in a definition with a base, a non-empty string")
        bp = p.parent / base
        inherited = _read_definition(bp)
        for key in ("base", "multiple_scattering"):
            if key in inherited:
                raise DatabaseError(f"{bp}: {key}: not allowed in the base of {p} (one level of base only)")
        data = {**inherited, **{k: v for k, v in data.items() if k != "base"}}
    ms = data.get("multiple_scattering", False)
    if not isinstance(ms, bool):
        raise DatabaseError(f"{p}: multiple_scattering: {ms!r} is not a boolean (true or false)")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise DatabaseError(f"{p}: name: required, a non-empty string")
    sim = data.get("simulation", {})
    _check_simulation(p, sim)
    qualities = data.get("quality", {})
    if not isinstance(qualities, dict) or not qualities:
        raise DatabaseError(f"{p}: quality: a table of positive ray counts per quality name is required")
    for q, v in qualities.items():
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise DatabaseError(f"{p}: quality.{q}: {v!r} is not a positive integer (rays per slice)")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise DatabaseError(f"{p}: description: {description!r} is not a string")
    symbols = data.get("symbols", {})
    families = data.get("family", [])
    if not families:
        raise DatabaseError(f"{p}: family: at least one [[family]] is required")
    param_rule = sim.get("parametrization", "classic")
    materials: list[Material] = []
    for fi, fam in enumerate(families):
        materials.extend(_expand_family(p, fi, fam, symbols, param_rule))
    if ms:
        materials = [dataclasses.replace(m, stack=m.stack.with_multiple_scattering()) for m in materials]
    seen: dict[str, int] = {}
    for i, m in enumerate(materials):
        if m.name in seen:
            raise DatabaseError(f"{p}: material name {m.name!r} is produced twice (materials {seen[m.name]} and {i})")
        seen[m.name] = i
    if "wavelength_bins" in sim and sim.get("spectral", False) is False:
        raise DatabaseError(_bins_without_spectral(p))
    # the values as the file gives them (their types are checked above; SimulationSettings checks the rest)
    db = Database(name=name, path=str(p),
                  incident_deg=tuple(float(x) for x in sim.get("incident_deg", DEFAULT_INCIDENT)),
                  resolution=tuple(sim.get("resolution", (90, 360))), seed=sim.get("seed", 1),
                  masking=sim.get("masking", "separable"), qualities=dict(qualities),
                  materials=tuple(materials), description=description,
                  spectral=sim.get("spectral", False), wavelength_bins=sim.get("wavelength_bins", DEFAULT_WAVELENGTH_BINS),
                  polarized=sim.get("polarized", False))
    try:   # every parametrization the materials use (one if they expand to none): the rest is shared
        for parametrization in dict.fromkeys(m.parametrization for m in materials) or DATABASE_PARAMETRIZATIONS[:1]:
            for q in qualities:
                db._settings(parametrization, q)
    except SettingsError as e:
        raise DatabaseError(f"{p}: simulation: {e}") from None
    _check_runs(p, db)
    return db


def _check_runs(p: Path, db: Database) -> None:
    """Refuse, before anything is traced, a material its run cannot trace: in a spectral database a
    stack whose spectra do not cover the bins (or a film the kernel cannot take), in an RGB one a
    thin film (its colours need wavelengths; ``docs/spectral.md``)."""
    if not db.materials:
        return
    settings = db.settings_for(db.materials[0], next(iter(db.qualities)))
    for m in db.materials:
        if not db.spectral:
            for i, x in enumerate(m.stack.layers):
                if isinstance(x, Interface) and x.film is not None and x.film.thickness_nm > 0.0:
                    raise DatabaseError(f"{p}: {m.name}: layers[{i}].film: a thin film needs a spectral run "
                                        f"(set spectral = true in [simulation]; docs/spectral.md)")
            continue
        from goniometer.run.launches import launch_stacks
        try:
            for _, stack, _ in launch_stacks(m.stack, settings):
                check_films(stack)
        except StackError as e:
            where = "" if str(e).startswith(f"{m.name}: ") else f"{m.name}: "
            raise DatabaseError(f"{p}: {where}{e}") from None


def _check_simulation(p: Path, sim: dict) -> None:
    """The types of the ``[simulation]`` values that :class:`SimulationSettings` would otherwise
    convert (a list of elevations, the resolution's list, the parametrization rule): DatabaseError,
    one line naming the field and what it takes. Nothing is converted: SimulationSettings checks
    the integers (``seed``, the resolution's), the names (``masking``) and every range."""
    def bad(message: str) -> DatabaseError:
        return DatabaseError(f"{p}: simulation: {message}")
    if "incident_deg" in sim:
        inc = sim["incident_deg"]
        if not isinstance(inc, list):
            raise bad(f"incident_deg: {inc!r} is not a list of elevations (numbers of degrees, each in [0, 90))")
        for x in inc:
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise bad(f"incident_deg: {x!r} is not a number (elevations in degrees, each in [0, 90))")
    if "resolution" in sim and not isinstance(sim["resolution"], list):
        raise bad(f"resolution: {sim['resolution']!r} is not [n_theta, n_phi] (a list of two integers)")
    rule = sim.get("parametrization", DATABASE_PARAMETRIZATIONS[0])
    names = ", ".join(DATABASE_PARAMETRIZATIONS)
    if isinstance(rule, str):
        if rule not in DATABASE_PARAMETRIZATIONS:
            raise bad(f"parametrization: {rule!r} is not one of {names} or the rule {PARAMETRIZATION_RULE}")
    elif isinstance(rule, dict):
        unknown = sorted(set(rule) - {"classic_if_alpha0_at_least", "otherwise"})
        if unknown:
            raise bad(f"parametrization.{unknown[0]}: unknown key of the rule {PARAMETRIZATION_RULE}")
        if "classic_if_alpha0_at_least" not in rule:
            raise bad(f"parametrization.classic_if_alpha0_at_least: required in the rule {PARAMETRIZATION_RULE}")
        a = rule["classic_if_alpha0_at_least"]
        if isinstance(a, bool) or not isinstance(a, (int, float)):
            raise bad(f"parametrization.classic_if_alpha0_at_least: {a!r} is not a number (the alpha0 from which "
                      f"materials use classic slices)")
        otherwise = rule.get("otherwise", "half")
        if not isinstance(otherwise, str) or otherwise not in DATABASE_PARAMETRIZATIONS:
            raise bad(f"parametrization.otherwise: {otherwise!r} is not one of {names}")
    else:
        raise bad(f"parametrization: {rule!r} is not one of {names} or the rule {PARAMETRIZATION_RULE}")


def _read_definition(p: Path) -> dict:
    data = read_toml(p, DatabaseError)
    allowed = {"name", "description", "base", "multiple_scattering", "simulation", "quality", "symbols", "family"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise DatabaseError(f"{p}: {unknown[0]}: unknown key (allowed: {', '.join(sorted(allowed))})")
    sim = data.get("simulation", {})
    if not isinstance(sim, dict):
        raise DatabaseError(f"{p}: simulation: {sim!r} is not a table")
    unknown = sorted(set(sim) - set(SIMULATION_KEYS))
    if unknown:
        raise DatabaseError(f"{p}: simulation.{unknown[0]}: unknown key (allowed: {', '.join(sorted(SIMULATION_KEYS))})")
    return data


def _expand_family(path: Path, fi: int, fam: dict, symbols: dict, param_rule) -> Iterator[Material]:
    where = f"{path}: family[{fi}]"
    for key in ("category", "name", "layers"):
        if key not in fam:
            raise DatabaseError(f"{where}.{key}: required")
    grid = fam.get("grid", {})
    variants = fam.get("variants", [{}])
    keys = list(grid)
    for values in itertools.product(*(grid[k] for k in keys)):
        for variant in variants:
            params = dict(zip(keys, values))
            params.update(variant)
            try:
                name = fam["name"].format(**params)
            except (KeyError, IndexError) as e:
                raise DatabaseError(f"{where}.name: {fam['name']!r} uses an unknown parameter {e}") from None
            layers = [_substitute(layer, params, symbols, f"{where} ({name})") for layer in fam["layers"]]
            try:
                stack = stack_from_dict({"name": name, "category": fam["category"], "layers": layers},
                                        source=f"{path}: {name}")
            except StackError as e:
                raise DatabaseError(str(e)) from None
            reported = {}
            for k in PARAMS_REPORTED:
                if k in params:
                    v = params[k]
                    if isinstance(v, str) and k in symbols:
                        reported[f"{k}_name"] = v
                        v = symbols[k][v]
                    reported[k] = v
            yield Material(name=name, category=fam["category"], paper_name=str(params.get("variant", name)),
                           stack=stack, params=reported, parametrization=_parametrization(param_rule, params, where))


def _substitute(value: Any, params: dict, symbols: dict, where: str) -> Any:
    if isinstance(value, dict):
        return {k: _substitute(v, params, symbols, where) for k, v in value.items()}
    if isinstance(value, list):
        return [_substitute(v, params, symbols, where) for v in value]
    if isinstance(value, str) and value.startswith("$"):
        key = value[1:]
        if key not in params:
            raise DatabaseError(f"{where}: {value!r} names no parameter (have: {', '.join(params)})")
        v = params[key]
        if isinstance(v, str):
            if key not in symbols or v not in symbols[key]:
                raise DatabaseError(f"{where}: {key} = {v!r} is not a symbol of [symbols.{key}]")
            v = symbols[key][v]
        return v
    return value


def _parametrization(rule, params: dict, where: str) -> str:
    """A material's parametrization: ``rule`` (checked by :func:`_check_simulation`) is a name or
    the rule on its ``alpha0``."""
    if isinstance(rule, str):
        return rule
    a0 = params.get("alpha0")
    if a0 is None:
        raise DatabaseError(f"{where}: the parametrization rule needs an alpha0 parameter")
    return "classic" if a0 >= rule["classic_if_alpha0_at_least"] else rule.get("otherwise", "half")


# ---------------------------------------------------------------------- results directory

def material_path(out_dir: Path, material: Material) -> Path:
    return Path(out_dir) / f"{material.name}.h5"


def _partial_dir(out_dir: Path, material: Material) -> Path:
    return Path(out_dir) / ".partial" / material.name


def paths_per_incident(db: Database, material: Material, quality: str) -> int:
    """Paths one incident direction of ``material``'s run at ``quality`` traces: the quality's rays,
    times a spectral run's launches (``docs/spectral.md`` section 1; what ``progress`` counts)."""
    settings = db.settings_for(material, quality)
    if not settings.spectral:
        return settings.rays
    from goniometer.run.launches import launches
    return settings.rays * len(launches(material.stack, settings))


def checkpointed_incidents(out_dir: Path, material: Material) -> int:
    """Number of incident directions of ``material`` kept in checkpoints under ``out_dir``."""
    return len(list(_partial_dir(out_dir, material).glob("m*.npz")))


def material_checkpoints(db: Database, out_dir: Path, material: Material, quality: str, threads: int | None = None,
                         on_discard: Callable[[Path, str], None] | None = None) -> Checkpoints:
    """The checkpoints of ``material``'s run at ``quality`` in ``out_dir/.partial/<name>/``: their
    ``meta.json`` holds the database's fingerprint, the quality, the material's name and its run
    description (``docs/database-format.md`` section 3)."""
    settings = db.settings_for(material, quality, threads)
    meta = {"fingerprint": db.fingerprint(), "quality": quality, "material": material.name,
            "run": run_description(material.stack, settings)}
    return Checkpoints(_partial_dir(out_dir, material), meta, on_discard)


def check_checkpoints(db: Database, out_dir: str | Path, quality: str, materials: list[Material]) -> None:
    """Raise :class:`~goniometer.run.checkpoints.CheckpointMismatch` if ``out_dir`` keeps checkpoints of
    one of ``materials`` that their runs at ``quality`` cannot use (another run, another version of
    the simulator code): the first such material's differences, and how many more there are.
    Nothing is changed; ``gonio database simulate --restart`` discards them."""
    found = []
    for m in materials:
        try:
            material_checkpoints(db, Path(out_dir), m, quality).check()
        except CheckpointMismatch as e:
            found.append(e)
    if found:
        first = found[0]
        raise CheckpointMismatch(first.directory, first.differences, first.reason, others=len(found) - 1)


def _manifest(db: Database, quality: str) -> dict:
    """The manifest of a results directory (``docs/database-format.md`` section 2.1); a spectral
    database's also says so (an RGB database's keeps its keys)."""
    out = {"format": RESULTS_FORMAT, "format_version": RESULTS_VERSION, "slices_format": store.FORMAT,
           "slices_format_version": store.FORMAT_VERSION, "database": db.name, "fingerprint": db.fingerprint(),
           "quality": quality, "rays_per_slice": db.qualities[quality],
           "definition": str(Path(db.path).resolve())}
    if db.spectral:
        out["spectral"] = True
        out["wavelength_bins"] = db.wavelength_bins
    if db.polarized:
        out["polarized"] = True
    return out


def check_results_dir(db: Database, out_dir: Path, quality: str) -> None:
    """Refuse a directory that holds results of another database, quality or format version."""
    out = Path(out_dir)
    mf = out / MANIFEST
    want = _manifest(db, quality)
    if mf.exists():
        try:
            have = json.loads(mf.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise DatabaseError(f"{mf}: unreadable manifest ({e}); move the directory aside") from None
        for key, label in (("format", "format"), ("format_version", "format version"),
                           ("slices_format_version", "slices format version"), ("database", "database"),
                           ("fingerprint", "database definition"), ("quality", "quality")):
            if have.get(key) != want[key]:
                raise DatabaseError(f"{out}: holds results of {label} {have.get(key)!r}, not {want[key]!r}; "
                                    f"use another --out (nothing was changed)")
    elif out.exists() and any(out.rglob("*.h5")):
        raise DatabaseError(f"{out}: holds .h5 files but no {MANIFEST}: not a results directory of "
                            f"`gonio database simulate`; use another --out (nothing was changed)")


def material_status(db: Database, out_dir: Path, material: Material, quality: str) -> str:
    """``"done"``, ``"partial"`` (checkpoints exist), ``"missing"`` or ``"corrupt"``."""
    p = material_path(out_dir, material)
    if p.exists():
        try:
            stack, settings = store.describe(p)
        except store.StoreError:
            return "corrupt"
        expected = db.settings_for(material, quality)
        if stack.to_json() != material.stack.to_json() or not same_run(settings, expected):
            return "corrupt"
        return "done"
    if checkpointed_incidents(out_dir, material):
        return "partial"
    return "missing"


@dataclass
class RunSummary:
    simulated: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    resumed: list[str] = field(default_factory=list)
    resimulated: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0


def simulate_database(db: Database, out_dir: str | Path, quality: str = "quick", only: str | None = None,
                      threads: int | None = None, scheduler: str | None = None,
                      resimulate_corrupted: bool = False,
                      progress: Callable[[int], None] | None = None,
                      on_material: Callable[[Material, str], None] | None = None,
                      client: Any = None, overwrite: bool = False, restart: bool = False,
                      on_discard: Callable[[Path, str], None] | None = None) -> RunSummary:
    """Simulate the selected materials of ``db`` into ``out_dir`` (resumable; see module docstring).

    ``progress(rays)`` is called as rays finish (for an overall bar); ``on_material(material,
    status)`` when a material starts (status as :func:`material_status`). ``scheduler`` (a Dask
    address such as ``tcp://host:8786``) or ``client`` (a ``distributed.Client``) runs the
    (material, incident, task) tasks on a Dask cluster; results are bit-identical to a local run.
    A spectral database (``spectral = true``) runs every material spectrally, through the same
    :func:`goniometer.run.loop.run_incidents` (and so on a cluster with a local run's bits;
    ``progress`` then counts the paths of its launches, :func:`paths_per_incident`).
    The kernel is compiled on first use unless the caller has compiled it
    (:func:`goniometer.run.tasks.warm_up_runs` of :func:`runs`). ``overwrite``: the selected finished
    materials are simulated again and their files replaced (``docs/outputs.md``); without it they
    are skipped. Checkpoints of a material that its run cannot use (another run, another code
    version) raise :class:`~goniometer.run.checkpoints.CheckpointMismatch` before anything is written
    (:func:`check_checkpoints`); ``restart`` discards the checkpoints of the materials to simulate
    instead, and they are traced from the start. ``on_discard(path, reason)``: told of an
    unreadable checkpoint file, whose direction is traced again
    (:class:`~goniometer.run.checkpoints.Checkpoints`).
    """
    out = Path(out_dir)
    materials = db.select(only)
    check_results_dir(db, out, quality)
    statuses = {m.name: material_status(db, out, m, quality) for m in materials}
    corrupt = [n for n, s in statuses.items() if s == "corrupt"]
    if corrupt and not resimulate_corrupted:
        raise DatabaseError(f"{out}: {len(corrupt)} finished file(s) cannot be read or do not match the database "
                            f"(first: {material_path(out, next(m for m in materials if m.name == corrupt[0]))}); "
                            f"rerun with --resimulate-corrupted to move them aside and simulate them again")
    chosen = [m for m in materials if overwrite or statuses[m.name] != "done"]
    if restart:
        for m in chosen:
            material_checkpoints(db, out, m, quality).clear()
            if statuses[m.name] == "partial":
                statuses[m.name] = "missing"
    check_checkpoints(db, out, quality, chosen)
    out.mkdir(parents=True, exist_ok=True)
    mf = out / MANIFEST
    if not mf.exists():
        atomic.write_bytes(mf, json.dumps(_manifest(db, quality), indent=2).encode())
    summary = RunSummary()
    t0 = time.perf_counter()
    todo = []
    for m in materials:
        st = statuses[m.name]
        if st == "done" and not overwrite:
            summary.skipped.append(m.name)
            continue
        if st == "done":
            summary.resimulated.append(m.name)
        if st == "corrupt":
            p = material_path(out, m)
            os.replace(p, p.with_name(p.name + f".corrupt-{int(time.time())}"))
            summary.resimulated.append(m.name)
        elif st == "partial":
            summary.resumed.append(m.name)
        todo.append(m)
    own_client = None
    if scheduler is not None and client is None:
        from goniometer.run.distributed import ClusterError, dask_client
        try:
            client = own_client = dask_client(scheduler)
        except ClusterError as e:
            raise DatabaseError(str(e)) from None
    try:
        for m in todo:
            if on_material is not None:
                on_material(m, statuses[m.name])
            _simulate_material(db, out, m, quality, threads, progress, client, on_discard)
            summary.simulated.append(m.name)
    finally:
        if own_client is not None:
            own_client.close()
    summary.elapsed_s = time.perf_counter() - t0
    return summary


def runs(db: Database, materials: list[Material], quality: str) -> list[tuple[Stack, SimulationSettings]]:
    """The (stack, settings) of each material's run at ``quality`` (to compile their kernel
    variants before tracing: :func:`goniometer.run.tasks.warm_up_runs`)."""
    return [(m.stack, db.settings_for(m, quality)) for m in materials]


def _simulate_material(db: Database, out: Path, material: Material, quality: str, threads: int | None,
                       progress: Callable[[int], None] | None, client: Any,
                       on_discard: Callable[[Path, str], None] | None = None) -> Path:
    settings = db.settings_for(material, quality, threads)
    checkpoints = material_checkpoints(db, out, material, quality, threads, on_discard)
    result = run_incidents(material.stack, settings, checkpoints=checkpoints, client=client, progress=progress)
    path = material_path(out, material)
    path.parent.mkdir(parents=True, exist_ok=True)
    store.write(path, result)
    checkpoints.clear()
    _remove_empty_parents(checkpoints.directory.parent, out / ".partial")
    return path


def _remove_empty_parents(directory: Path, stop: Path) -> None:
    """Remove ``directory`` and its parents up to and including ``stop`` while they are empty."""
    d = directory
    while True:
        try:
            d.rmdir()
        except OSError:
            return
        if d == stop:
            return
        d = d.parent


def list_rows(db: Database, out_dir: str | Path | None = None, quality: str = "quick") -> list[dict]:
    """One row per material for ``gonio database list`` (with its status if ``out_dir`` is given)."""
    rows = []
    for m in db.materials:
        row = {"name": m.name, "category": m.category, "paper_name": m.paper_name,
               "parametrization": m.parametrization, **m.params}
        if out_dir is not None:
            row["status"] = material_status(db, Path(out_dir), m, quality)
        rows.append(row)
    return rows
