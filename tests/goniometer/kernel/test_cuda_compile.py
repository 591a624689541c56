"""The CUDA kernel compiled for GPUs without a GPU (``docs/gpu.md``, compiled in CI): every variant
the simulator launches, for sm_80 and sm_90, through NVVM and ``ptxas -v``
(``goniometer.kernel.cuda_build``): no compile error, no spilled register (but the polarized film
variants' few bytes on sm_80), within its launch bounds (25 % occupancy for scalar light without a
film); the report's parser and the occupancy formula. The regular suite compiles the separable
variant without a film (the tightest budget: 128 registers), ``make test-slow`` the other seven
(films, height-correlated, polarized)."""

from __future__ import annotations

import importlib.util

import pytest

from goniometer.kernel import cuda_build

HAS_NUMBA_CUDA = importlib.util.find_spec("numba_cuda") is not None
PTXAS = cuda_build.ptxas_path()
#: where the toolkit is missing the compile is skipped, saying what is missing (CI installs the test
#: extra, which brings both)
needs_toolkit = pytest.mark.skipif(
    not HAS_NUMBA_CUDA or PTXAS is None,
    reason="numba-cuda is not installed (pip install 'goniometer[test]')" if not HAS_NUMBA_CUDA else
    "ptxas is not found: the CUDA toolkit wheels are not installed (pip install 'numba-cuda[cu12]')")


#: the variant the regular suite compiles: separable masking without a film, held to 128 registers
#: (``make test-slow`` compiles the other seven, with films, height-correlated and polarized: NVVM
#: takes about a minute per variant on a 2-core machine; the regular suite runs their code under the
#: simulator, test_cuda.py)
REGULAR = {(None, None, None)}

#: spilled bytes a variant may have: none, but ptxas spills 32 bytes a thread of the polarized film
#: variants for sm_80 at 255 registers (docs/gpu.md)
SPILL_ALLOWED = {("sm_80", "film polarized"): 64, ("sm_80", "height-correlated film polarized"): 64}


@pytest.fixture(scope="module")
def report():
    return cuda_build.build_report(ptxas=PTXAS, variants=REGULAR)


def _check_variants(r: dict, arch: str) -> None:
    for name, v in r["variants"].items():
        assert v["spill_bytes"] <= SPILL_ALLOWED.get((arch, name), 0), f"{arch} {name}: {v}"
        assert 0 < v["registers"] <= v["max_registers"], f"{arch} {name}: {v}"
        # scalar light without a film: 128 registers, four blocks of 128 threads, a quarter of the
        # threads resident; polarized light: 255 registers, two blocks, an eighth
        if "film" not in name and "polarized" not in name:
            assert v["max_registers"] == 128 and v["occupancy"] >= 0.25, f"{arch} {name}: {v}"
        if "polarized" in name:
            assert v["max_registers"] == 255 and v["occupancy"] >= 0.125, f"{arch} {name}: {v}"


@needs_toolkit
@pytest.mark.parametrize("arch", ["sm_80", "sm_90"])
def test_every_variant_compiles_without_spilling(report, arch):
    r = report[arch]
    assert set(r["variants"]) == {cuda_build.VARIANT_NAMES[k] for k in REGULAR}, r["variants"].keys()
    _check_variants(r, arch)
    assert r["registers"] == max(v["registers"] for v in r["variants"].values())


@needs_toolkit
@pytest.mark.slow
def test_the_other_variants_compile():
    others = set(cuda_build.VARIANT_NAMES) - REGULAR
    rep = cuda_build.build_report(ptxas=PTXAS, variants=others)
    for arch, r in rep.items():
        assert set(r["variants"]) == {cuda_build.VARIANT_NAMES[k] for k in others}, r["variants"].keys()
        _check_variants(r, arch)


@needs_toolkit
def test_the_check_sees_spills():
    """The same report, of the same PTX, when its launch bounds leave 64 registers a thread
    (eight blocks of 128 threads): spills."""
    (key, sig), = [(k, s) for k, s in cuda_build.launch_signatures() if k == (None, None, None)]
    ptx = cuda_build.compile_ptx((9, 0), key, sig)
    assert ".minnctapersm 4" in ptx and cuda_build.ptxas_report(ptx, (9, 0), PTXAS)["spill_bytes"] == 0
    low = cuda_build.ptxas_report(ptx.replace(".minnctapersm 4", ".minnctapersm 8"), (9, 0), PTXAS)
    assert low["registers"] <= 64 and low["spill_bytes"] > 0, low


_PTXAS_V = """ptxas info    : 352 bytes gmem
ptxas info    : Function properties for __internal_lgamma_pos
    8 bytes stack frame, 0 bytes spill stores, 0 bytes spill loads
ptxas info    : Compiling entry function '_ZN6kernelE' for 'sm_90'
ptxas info    : Function properties for _ZN6kernelE
    232 bytes stack frame, 900 bytes spill stores, 904 bytes spill loads
ptxas info    : Used 128 registers, used 1 barriers, 232 bytes cumulative stack size, 14640 bytes smem
ptxas info    : Compile time = 1492.813 ms
"""


def test_the_report_reads_the_entry_function():
    assert cuda_build._entry_report(_PTXAS_V, "sm_90") == {"registers": 128, "spill_bytes": 1804,
                                                           "stack_bytes": 232, "shared_bytes": 14640}
    with pytest.raises(cuda_build.BuildError, match="no entry function for sm_80"):
        cuda_build._entry_report(_PTXAS_V, "sm_80")


def test_occupancy():
    """Resident threads per multiprocessor / 2048 (blocks of 128 threads): limited by registers
    (65536 a multiprocessor, allocated per warp in units of 256), by 2048 threads, by shared memory
    (164 KB on sm_80, 228 KB on sm_90, 1 KB reserved per block)."""
    occ = cuda_build.occupancy
    assert occ(222, 304, (9, 0), 128) == 0.125     # the kernel before issue 32: 2 blocks
    assert occ(128, 304, (9, 0), 128) == 0.25
    assert occ(129, 304, (9, 0), 128) == 0.1875    # 136 registers a thread once rounded to the unit
    assert occ(168, 21808, (8, 0), 128) == 0.1875
    assert occ(32, 304, (9, 0), 128) == 1.0        # 16 blocks: the thread limit
    assert occ(32, 100_000, (8, 0), 128) == 0.0625  # one block's shared memory fills an A100's
    assert occ(32, 100_000, (9, 0), 128) == 0.125   # two fit an H100's


@needs_toolkit
@pytest.mark.slow
def test_nvvm_gives_each_architecture_the_same_ptx():
    """What lets the check compile each variant once (``cuda_build`` module docstring): NVVM's PTX for
    9.0 is the 8.0 PTX with its ``.target``, but for the names numba makes unique per compile."""
    import re

    def names_out(ptx: str) -> str:
        return re.sub(r"_cudapy_smem_\d+", "S", re.sub(r"_Z\w+", "N", ptx))

    (key, sig), = [(k, s) for k, s in cuda_build.launch_signatures() if k == (True, True, None)]
    native = cuda_build._compiled_ptx((9, 0), key, sig)
    assert ".target sm_90" in native
    assert names_out(native) == names_out(cuda_build.compile_ptx((9, 0), key, sig))
