"""rsal.suggest: the platform's one "did you mean", shared by the driver layer and the scenarios."""

from pathlib import Path

from rsal.suggest import did_you_mean

ROOT = Path(__file__).resolve().parents[2]


def test_the_nearest_known_name_or_none():
    assert did_you_mean("safety_distance", ["safety_dist", "max_radius"]) == "safety_dist"
    assert did_you_mean("zzz", ["safety_dist", "max_radius"]) is None
    assert did_you_mean("q", ["mapfile"], cutoff=0.0) == "mapfile"  # any name at all when asked
    assert did_you_mean(3, {"3x": 1}) == "3x"  # keys of a mapping; the word need not be a str


def test_the_driver_layer_re_exports_it():
    from mrs_bridge import params

    assert params.did_you_mean is did_you_mean


def test_the_product_asks_difflib_in_one_place():
    # The simulator imports nothing of ours and keeps its own helper; agents/, mrs_bridge/ and rsal/
    # ask rsal.suggest.
    users = [
        str(p.relative_to(ROOT))
        for pkg in ("agents", "mrs_bridge", "rsal")
        for p in sorted((ROOT / pkg).rglob("*.py"))
        if "get_close_matches" in p.read_text(encoding="utf-8")
    ]
    assert users == ["rsal/suggest.py"]
