"""The shared command-line helpers (rsal/cliutil.py): the short form of long name lists and the
positive-number argument type."""

from __future__ import annotations

import argparse

import pytest

from rsal.cliutil import brief, positive


def test_brief_folds_runs_of_consecutive_numbers_and_keeps_the_order():
    assert brief([f"r{i}" for i in range(1000)]) == "r0..r999"
    assert brief(["r0", "r1", "hunter", "r3", "r4", "r5", "x10", "x11"]) == "r0, r1, hunter, r3..r5, x10, x11"
    assert brief(["r2", "r1", "r0"]) == "r2, r1, r0"  # not sorted: the order the caller gave
    assert brief(["r01", "r02", "r9", "r10"]) == "r01, r02, r9, r10"  # leading zeros are not numbers here
    assert brief([]) == ""


def test_brief_cuts_a_long_list_and_gives_the_total():
    text = brief([f"a{i}" for i in range(0, 100, 2)], limit=5)
    assert text == "a0, a2, a4, a6, ... (50 in all)"


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "inf", "x"])
def test_positive_rejects_what_is_not_a_finite_positive_number(bad):
    with pytest.raises(argparse.ArgumentTypeError):
        positive(bad)
    assert positive("0.5") == 0.5


def test_first_few_logs_a_few_lines_of_a_kind_then_says_the_rest_are_at_debug_level(caplog):
    import logging

    from rsal.cliutil import FirstFew

    log = logging.getLogger("test.firstfew")
    few = FirstFew("robots started", n=3)
    with caplog.at_level(logging.INFO, logger="test.firstfew"):
        for i in range(50):
            few.log(log, logging.INFO, "r%d: started", i)
    assert [r.getMessage() for r in caplog.records] == [
        "r0: started",
        "r1: started",
        "r2: started",
        "more robots started; each at debug level (-vv)",
    ]
    caplog.clear()
    with caplog.at_level(logging.DEBUG, logger="test.firstfew"):
        few.log(log, logging.INFO, "r50: started")
    assert [(r.levelno, r.getMessage()) for r in caplog.records] == [(logging.DEBUG, "r50: started")]
