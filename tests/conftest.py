"""Shared fixtures of the test suite (stacks, a material file, a refusal's check, the slow cases).

The statistical checks (false-alarm probability, chi-square limits, cells against a model, two
samples, energies) are the library's, :mod:`goniometer.testing` (``docs/testing.md``), which the
tests import as a plugin author's tests do."""

from __future__ import annotations

import os
import signal

# Under pytest-xdist (`make test` runs two workers) the workers share one numba cache, set before
# numba is first imported (numba writes each cache file whole and replaces it atomically; the
# failure once blamed on sharing was the error-model one, docs/kernel.md section 5). The CLI
# subprocesses a worker starts inherit it.
if os.environ.get("PYTEST_XDIST_WORKER") and not os.environ.get("NUMBA_CACHE_DIR"):
    os.environ["NUMBA_CACHE_DIR"] = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                                 "build", "numba-cache", "shared")

import pytest  # noqa: E402

from goniometer.stack import Interface, Lambertian, Medium, Stack  # noqa: E402


@pytest.fixture
def plastic() -> Stack:
    return Stack("plastic", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Lambertian((0.2, 0.5, 0.8))),
                 "plastic")


@pytest.fixture
def metal() -> Stack:
    return Stack("metal", (Interface(0.2, (1.5,) * 3), Medium((0.2,) * 3),
                           Interface(0.2, (1.45,) * 3, (1.0, 0.01, 0.01))), "metal")


@pytest.fixture
def slab() -> Stack:
    return Stack("slab", (Interface(0.05, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Interface(0.2, (1.0,) * 3)),
                 "slab")


#: a plastic material file for command tests (one dielectric interface over a Lambertian base); its
#: ``[simulation]`` table is appended by each test
PLASTIC_TOML = """name = "p"
category = "plastic"
[[layers]]
type = "interface"
roughness = 0.2
ior = 1.5
[[layers]]
type = "lambertian"
albedo = 0.5
"""


def child_sigint_default() -> None:
    """``preexec_fn`` of a child that a test interrupts: SIGINT at its default even when the suite
    runs as a background job (where the shell makes it ignored, and an ignored SIGINT is rightly
    left ignored by the child's Python). Nothing is imported here: the child runs it between fork
    and exec."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def refused(capsys, argv, *needles) -> str:
    """Run ``gonio argv``: exit status 2 and exactly one line ``gonio: error: ...`` holding every
    needle; returns that line."""
    from goniometer.cli import main
    capsys.readouterr()
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gonio: error: "), err
    for n in needles:
        assert str(n) in err[0], (n, err[0])
    return err[0]


#: physics checks that repeat a regular test's claim on a costlier case (a further kernel variant
#: to compile, a deeper walk), run by ``make test-slow`` (``-m slow``) rather than by every
#: ``make test``; each claim keeps a case in the regular suite (named after the arrow)
SLOW_CASES = {
    "tests/goniometer/test_cli.py::test_ctrl_c_leaves_no_partial_file[compiling]":
        "a fresh compile under Ctrl-C -> [tracing] stays",
    "tests/goniometer/test_multiple_scattering.py::test_multiple_scattering_brdf_is_reciprocal":
        "reciprocity of walks -> the white furnaces and first-bounce checks stay",
    "tests/goniometer/test_multiple_scattering.py::test_first_bounce_is_single_scattering[dielectric]":
        "-> [conductor] and [dielectric-inverted] stay",
    "tests/goniometer/test_multiple_scattering.py::test_white_furnace_dielectric[aniso]":
        "-> [a0.5], [a1], [eta0.6], [slab] stay",
    "tests/goniometer/test_first_order.py::test_multiple_scattering_top_integrates_its_one_bounce_walks[coat-over-cloud]":
        "-> the other stacks of the test stay",
    "tests/goniometer/kernel/test_two_kernels.py::test_tabulations_agree_between_kernels[scattering-ms-plastic]":
        "-> the other tabulation stacks stay",
    "tests/goniometer/kernel/test_two_kernels.py::test_lane_and_path_kernels_agree[ms-aniso-metal]":
        "-> [ms-slab], [aniso-plastic] and the other stacks stay",
    "tests/benchmarks/test_reference_kernel.py::test_reference_kernel_agrees_with_simulator[metal]":
        "-> [plastic] stays",
    "tests/goniometer/test_reached_base.py::test_light_that_turns_around_in_the_medium_matches_a_black_base_run":
        "-> test_everything_a_black_base_reflects_never_reached_it stays",
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.nodeid in SLOW_CASES:
            item.add_marker(pytest.mark.slow)
