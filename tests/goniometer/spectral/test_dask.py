"""A spectral run on a Dask cluster (docs/spectral.md section 1, docs/database-format.md section 4):
its (incident, launch, task) units traced on workers give the local spectral run's bits, for a
stack of three bins per launch and for a dispersive one of one bin per launch."""

from __future__ import annotations

import numpy as np
import pytest

import goniometer as g
from goniometer.run.loop import run_incidents
from goniometer.run.launches import launches
from goniometer.stack import stack_from_dict
from goniometer.run.tasks import n_tasks
from tests.goniometer.spectral.test_transport import GOLD

#: a dielectric of Cauchy index: traced one wavelength per launch
GLASS = {"name": "glass", "category": "slab", "layers": [
    {"type": "interface", "roughness": 0.2, "ior": {"cauchy": [1.5, 0.0042]}},
    {"type": "interface", "roughness": 0.2, "ior": 1.0}]}


def test_a_spectral_run_on_a_dask_cluster_gives_the_local_bits():
    distributed = pytest.importorskip("distributed", reason="Dask distributed is a test dependency")
    # 9 chunks in 5 tasks per launch, the last task one short chunk
    s = g.SimulationSettings(incident_deg=(0.0, 50.0), rays=4500, resolution=(6, 12), spectral=True,
                             wavelength_bins=6, threads=1, chunk_rays=512, chunks_per_task=2)
    assert n_tasks(s) == 5
    stacks = [stack_from_dict(GOLD), stack_from_dict(GLASS)]
    assert [len(launches(st, s)) for st in stacks] == [2, 6]
    local = [g.simulate(st, s) for st in stacks]
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        for st, a in zip(stacks, local):
            rays: list[int] = []
            b = run_incidents(st, s, client=client, progress=rays.append)
            assert sum(rays) == len(s.incident_deg) * s.rays * len(launches(st, s))
            assert b.brdf.value.shape == (2, 6, 6, 12)
            slices = [(a.brdf, b.brdf)] + ([(a.btdf, b.btdf)] if st.transmits else [])
            assert (a.btdf is None) == (b.btdf is None) == (not st.transmits)
            for x, y in slices:
                for name in ("value", "stderr", "stderr_internal", "orders"):
                    assert np.array_equal(getattr(x, name), getattr(y, name)), name
            for x, y in ((a.energy, b.energy), (a.energy_stderr, b.energy_stderr)):
                assert x.keys() == y.keys() and all(np.array_equal(x[key], y[key]) for key in x)
            for name in ("roulette", "capped", "capped_paths", "mean_events"):
                assert np.array_equal(getattr(a, name), getattr(b, name)), name
            assert np.all(b.elapsed_s > 0)
