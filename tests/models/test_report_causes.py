"""models.report.causes: every reproduction check that does not fully hold, or that is
noise-limited, carries a cause of the contract's kinds, and only those checks do."""

from __future__ import annotations

import re

import pytest

from models.report.causes import CAUSE_KINDS, INVESTIGATED, PAPER_RUN, QUICK_RUN, attach_causes, needs_cause


def check(cid="x", n=6, agree=6, verdict="holds", noise=0, noise_dis=0):
    return {"id": cid, "n": n, "agree": agree, "verdict": verdict, "noise_limited": noise,
            "noise_limited_disagreeing": noise_dis}


def test_only_checks_that_need_a_cause_get_one():
    held, empty = check(), check(n=0, agree=0, verdict="not testable")
    attach_causes([held, empty])
    assert "cause" not in held and "cause" not in empty
    assert needs_cause(check(verdict="partly", agree=4)) and needs_cause(check(noise=2))


def test_noise_when_every_disagreeing_comparison_is_noise_limited():
    c = check(agree=4, verdict="partly", noise=3, noise_dis=2)
    attach_causes([c])
    assert c["cause"] == "noise" and "3 of 6" in c["cause_text"]


def test_an_uninvestigated_real_disagreement_is_said_to_be_one():
    c = check(cid="not-a-check", agree=1, verdict="does not hold", noise=1, noise_dis=1)
    attach_causes([c])
    assert c["cause"] is None and "not investigated" in c["cause_text"]


def test_investigated_causes_are_of_the_contract_kinds_and_say_something():
    for cid, (cause, text) in INVESTIGATED.items():
        assert cause in CAUSE_KINDS, cid
        assert len(text) > 40, cid
        c = check(cid=cid, agree=0, verdict="does not hold")
        attach_causes([c])
        assert c["cause"] == cause and c["cause_text"].endswith(text)


#: the runs an investigation may quote; every number of its evidence must follow one of them
QUOTED = (QUICK_RUN, PAPER_RUN)


def _numbers(text: str) -> list[str]:
    """The numbers of a text, material names and check ids (which carry digits) left out."""
    text = re.sub(r"\b[\w.]*-a0_[\w.-]*", " ", text)            # material names
    text = re.sub(r"\b[a-z]+(?:-[a-z0-9.]+)+\b", " ", text)      # check ids, model names
    text = re.sub(r"\b(?:eq|table|section)\.? \d+", " ", text)    # references to the paper
    text = re.sub(r"\b[A-Z][a-z]+ (?:19|20)\d\d\b", " ", text)       # citations (Bati 2019)
    return re.findall(r"(?<!\w)\d+(?:[.,]\d+)*", text)


def _this_run_numbers(c: dict, run: dict) -> set[str]:
    return {str(c["n"]), str(c["agree"]), str(c["noise_limited"]), f"{run['rays_per_slice']:,}", str(run["materials"])}


@pytest.mark.parametrize("cid", sorted(INVESTIGATED))
def test_a_cause_text_follows_the_run_and_names_the_runs_it_quotes(cid):
    """The same check on two runs (a 4-material demo, the 60-material database at another quality):
    the text states each run's own counts and database, quality and rays per slice, and every other
    number sits after the name of the run it was measured on."""
    runs = [({"database": "demo4", "quality": "demo", "rays_per_slice": 500_000, "materials": 4}, (2, 1, 1)),
            ({"database": "bati2019", "quality": "paper", "rays_per_slice": 160_000_000, "materials": 60},
             (36, 17, 5))]
    texts = []
    for run, (n, agree, noise) in runs:
        c = check(cid=cid, n=n, agree=agree, verdict="does not hold", noise=noise)
        attach_causes([c], run)
        text = c["cause_text"]
        texts.append(text)
        own, _, quoted = text.partition(" Investigated: ")
        assert f"database {run['database']}" in own and f"quality {run['quality']}" in own
        assert f"{run['rays_per_slice']:,} rays per slice" in own and f"{run['materials']} materials" in own
        assert f"{agree} of {n} comparisons agree" in own and f"{noise} of them noise-limited" in own
        assert set(_numbers(own)) <= _this_run_numbers(c, run), own
        # the quoted evidence: every number comes after the name of a run, and rays are only those runs'
        first = min(quoted.find(q) for q in QUOTED if q in quoted)
        assert first >= 0 and not _numbers(quoted[:first]), quoted
        unnamed = quoted
        for q in QUOTED:
            unnamed = unnamed.replace(q, "")
        assert "rays" not in unnamed and "materials)" not in unnamed, unnamed
    assert texts[0] != texts[1]


def test_the_noise_cause_states_this_runs_counts():
    for run, n in (({"database": "a", "quality": "quick", "rays_per_slice": 30_000, "materials": 5}, 6),
                   ({"database": "b", "quality": "paper", "rays_per_slice": 160_000_000, "materials": 60}, 36)):
        c = check(n=n, agree=n - 2, verdict="holds", noise=3, noise_dis=2)
        attach_causes([c], run)
        assert c["cause"] == "noise" and f"3 of {n}" in c["cause_text"]
        assert f"database {run['database']}" in c["cause_text"] and f"{run['rays_per_slice']:,}" in c["cause_text"]
        assert set(_numbers(c["cause_text"])) <= _this_run_numbers(c, run) | {"2"}, c["cause_text"]
