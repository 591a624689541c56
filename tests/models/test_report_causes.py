"""models.report.causes: every reproduction check that does not fully hold, or that is
noise-limited, carries a cause of the contract's kinds, and only those checks do."""

from __future__ import annotations

from models.report.causes import CAUSE_KINDS, INVESTIGATED, attach_causes, needs_cause


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
        assert (c["cause"], c["cause_text"]) == (cause, text)
