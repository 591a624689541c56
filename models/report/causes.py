"""Why a reproduction finding does not fully hold: the cause of every check whose verdict is not
"holds" or that has noise-limited comparisons (``reproduction.json`` keys ``cause`` and
``cause_text``; ``docs/report.md``, reproduction).

A cause is one of :data:`CAUSE_KINDS`: our ``"implementation"`` (found and fixed: the text says
what changed), our ``"reading"`` of the paper's sentence (the text says what else it could mean
and where that reading is tested), the ``"paper"`` (its own statement does not hold under its own
model or data), or ``"noise"`` (the comparisons differ by less than the reference's noise floor).
The investigated causes (:data:`INVESTIGATED`) are findings with their evidence, measured on the
60-material database (quick quality, 4 M rays per slice) and, for the deciding materials, at the
paper's quality (160 M rays per slice); they apply only while the check still needs a cause. A
check that needs one and was not investigated gets ``"noise"`` when every disagreeing comparison
is noise-limited, else ``cause: null`` with a note saying so.
"""

from __future__ import annotations

CAUSE_KINDS = ("implementation", "reading", "paper", "noise")

#: check id -> (cause, evidence)
INVESTIGATED: dict[str, tuple[str, str]] = {
    "plastic-tau": (
        "reading",
        "Read per channel in absolute terms, the error falls as tau grows: absorption removes internal light, so "
        "the most absorbed channel has the least to get wrong (P2-a0_0.05, tau = 0.05/0.1/0.4: ww09 RMSE "
        "0.103/0.091/0.042, the same at 160 M rays). Read relative to the reference's own size (check "
        "plastic-tau-relative: RMSE / eq. 4 norm of the reference), the error grows with tau on 6/6 "
        "(ww09 0.86/0.91/0.95, elek10 0.94/1.05/1.35): that reading holds."),
    "metal-belcour-sym-total": (
        "noise",
        "At 4 M rays per slice all 36 total-BRDF comparisons differ by less than the noise floor: the sharp top "
        "reflection dominates the total error (M1-a0_0.001-a1_0.2: 3.63 vs 3.65). At the paper's 160 M rays the "
        "five deciding metals agree, three of them beyond the noise floor (M4-a0_0.05-a1_0.2: 0.438 vs 0.566); on "
        "the alpha0 = 0.2 frosted metals the gap (0.196 vs 0.198) stays below it: 'slightly' is too slight there."),
    "metal-belcour-bati19-total": (
        "noise",
        "16 of 36 comparisons are within the noise floor at 4 M rays per slice, where the smooth coats' top "
        "reflection dominates the total error. At the paper's 160 M rays eq. 6 is ahead on all five deciding "
        "metals, four of them beyond the noise floor (M4-a0_0.05-a1_0.2: 0.044 vs 0.566); on the smooth-coat "
        "M1-a0_0.001-a1_0.2 (0.906 vs 0.982) the gap is still within it."),
    "metal-a1-0.001-a0-0.2-elek-same": (
        "paper",
        "Both models follow the paper (Elek as Bati 2019 table 2, checked by hand at normal incidence; Belcour as "
        "Belcour's reference code with the setup Bati states), yet Elek's error is 17-21 % lower (ratio 0.79-0.83; "
        "0.74-0.83 under every stated or code-faithful option) because Belcour's internal lobe, exact up to "
        "theta_l = 30 deg, is 4-15x too peaked and 1.7-3.4x too bright at 60-80 deg (92 % of its eq. 4 error). "
        "Parity within 1.1 needs the TIR step plus statistics on the view side (1.05-1.08), which the paper does "
        "not state; scoring only theta_l <= 60 deg would reverse the ranking (1.26-1.33)."),
    "metal-belcour-best": (
        "paper",
        "Holds on the 24 metals with a smooth or paint-like coat (Belcour 2.2-9.2x better) and fails exactly on "
        "the 12 frosted metals (alpha1 = 0.001, alpha0 >= 0.05; Elek / Belcour 0.79-0.90), for the reason of "
        "metal-a1-0.001-a0-0.2-elek-same: Belcour's grazing-angle internal lobe dominates eq. 4 over incidences "
        "0-80 deg. It would hold 30/36 with Belcour's TIR step and 36/36 if only theta_l <= 60 deg were scored; "
        "the paper does not say which incidences it used."),
}


def needs_cause(check: dict) -> bool:
    """A check needs a cause when it was testable and does not fully hold or is noise-limited."""
    return check["n"] > 0 and (check["verdict"] != "holds" or check["noise_limited"] > 0)


def attach_causes(checks: list[dict]) -> list[dict]:
    """Add ``cause`` and ``cause_text`` to every check that needs them (in place; returns ``checks``)."""
    for c in checks:
        if not needs_cause(c):
            continue
        known = INVESTIGATED.get(c["id"])
        disagree = c["n"] - c["agree"]
        if known is not None:
            cause, text = known
        elif disagree == c.get("noise_limited_disagreeing", 0):
            cause = "noise"
            text = (f"{c['noise_limited']} of {c['n']} comparisons differ by less than the reference's noise floor"
                    + (f", including every one of the {disagree} that disagree" if disagree else "")
                    + ": a finer reference (more rays) decides them.")
        else:
            cause, text = None, "not investigated: no cause is known for this outcome."
        assert cause is None or cause in CAUSE_KINDS
        c["cause"] = cause
        c["cause_text"] = text
    return checks
