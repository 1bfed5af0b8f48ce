"""Test rigs of the navigation algorithms: in-process simulations that tests and benchmarks drive.

- :mod:`mrs_bridge.rigs.localsim`: one local planner (``mrs_bridge.nav.local``) driving a simulated
  robot with a perfect laser, no fabric (``tests/nav/test_local.py``, ``benchmarks/bench_local.py``);
- :mod:`mrs_bridge.rigs.stacksim`: the whole navigation stack of ``rsal sim --nav`` (amcl, wavefront,
  a local planner) in one process on a simulated world (``tests/nav/test_nav_success.py``,
  ``benchmarks/bench_nav.py``).

They live apart from :mod:`mrs_bridge.nav` so that the algorithms never import a rig: the arrows
point from the rigs to the algorithms (and to ``simulator``), never back.
"""
