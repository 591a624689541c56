"""What the tests of the open harness share (tests/models/test_plugins.py, test_adapters.py): a
distribution made by hand on ``sys.path`` (a ``NAME-VERSION.dist-info`` with METADATA and
entry_points.txt, the way pip leaves one) and tiny simulated files."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import goniometer as g
from goniometer.stack import Stack
from models import plugins

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "plugin-model"


class Installer:
    """Puts hand-made distributions on ``sys.path`` for one test (monkeypatch) and clears the
    registry's entry-point scan before and after. The scan is the real one
    (``importlib.metadata.entry_points``) with the entry points of distributions installed
    elsewhere left out, so that the tests hold whether or not ``make setup`` installed
    examples/plugin-model."""

    def __init__(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        self.tmp, self.monkeypatch, self.modules, self.roots = tmp_path, monkeypatch, [], []
        real = plugins.entry_points

        def ours(group: str):
            return [ep for ep in real(group=group)
                    if ep.dist is not None and Path(str(ep.dist.locate_file(""))).resolve() in self.roots]
        monkeypatch.setattr(plugins, "entry_points", ours)
        plugins.clear_cache()

    def install(self, dist: str, version: str, entries: dict[str, str], modules: dict[str, str]) -> Path:
        """A directory holding ``modules`` (module name -> source) and the dist-info of ``dist``
        with ``entries`` (entry point name -> "module:Class") in the group goniometer.models."""
        root = self.tmp / f"site-{dist}"
        info = root / f"{dist.replace('-', '_')}-{version}.dist-info"
        info.mkdir(parents=True)
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
        lines = [f"[{plugins.GROUP}]"] + [f"{k} = {v}" for k, v in entries.items()]
        (info / "entry_points.txt").write_text("\n".join(lines) + "\n")
        for name, source in modules.items():
            (root / f"{name}.py").write_text(source)
            self.modules.append(name)
        self.monkeypatch.syspath_prepend(str(root))
        self.roots.append(root.resolve())
        plugins.clear_cache()
        return root

    def example(self) -> Path:
        """examples/plugin-model as pip would install it (without pip)."""
        source = (EXAMPLE / "example_plugin.py").read_text()
        return self.install("example-plugin", "0.1", {"coated-diffuse": "example_plugin:CoatedDiffuse"},
                            {"example_plugin": source})

    def close(self) -> None:
        for name in self.modules:
            sys.modules.pop(name, None)
        plugins.clear_cache()


@pytest.fixture
def installer(tmp_path, monkeypatch):
    inst = Installer(tmp_path, monkeypatch)
    yield inst
    inst.close()


def tiny_file(path: Path, stack: Stack, rays: int = 20_000, incident: tuple[float, ...] = (30.0,),
              seed: int = 5) -> Path:
    """Simulate ``stack`` on a 9 x 18 classic grid and write it to ``path``."""
    settings = g.SimulationSettings(incident_deg=incident, rays=rays, resolution=(9, 18), seed=seed)
    g.write(path, g.simulate(stack, settings))
    return path
