"""The default navigation profile of a simulated Pioneer: the parameters ``rsal sim --nav`` gives
its drivers and the in-process stack (:mod:`mrs_bridge.rigs.stacksim`) uses, in one place.

Values follow the thesis's appendix A.3 where it sets them (wavefront ``distance_epsilon`` 0.4 m,
``angle_epsilon`` 10°, local planner tolerances tighter than the global ones, "set this to be
GREATER than the corresponding threshold of the underlying position device") and are tuned for
the project's maps otherwise. Units are the configuration file's: metres, **degrees**.
"""

from __future__ import annotations

__all__ = ["AMCL", "AMCL_SONAR", "WAVEFRONT", "LOCAL", "LOCAL_PLANNERS"]

#: amcl filter size and sensor model (the initial pose is the robot's; see sim_config). Recovery by
#: random particles is off: other robots and people, which are not on the map, lower the scan's fit
#: just as a kidnapping does, and the injected guesses then pull the estimate away (measured with
#: bench_nav: localization errors of 2-17 m with it on, under 0.25 m with it off). A lost robot is
#: re-localized with localize rpc/set_pose or rpc/set_global instead. For the same reason the
#: likelihood-field model gives unexplained returns more weight than Player's default (z_rand 0.2,
#: not 0.05): with 0.05 a passing robot's outline is fitted as a wall and the estimate walks off
#: (bench_nav, VFH, seed 11: 0.49 m worst error; with 0.2: 0.13 m), against the thesis's 0.30 m.
#: Readings cut short by such robots are left out once the filter is sure where it is (the distance
#: filter, nav.distfilter, 0.5 m): still weighed, a mover 1 m away dragged the estimate 0.28 m
#: (bench_nav, SND). The odometry noise is a Pioneer's (the simulator's: a 3 %/5 % scale error, 1-2 %
#: noise), not Player's 0.2 (45 % standard deviation), which kept the cloud 0.2 m wide.
#: Where the rangers see nothing on the map (a crowd in open space, sonars seeing only other robots)
#: Player's 0.2 also let the cloud's mean fall short of the robot (ten Pioneer 3-AT on sonar driving
#: arcs for 30 s: p95 error 1.43 m with 0.2, 0.58 m with 0.05, 0.36 m for dead reckoning).
AMCL: dict = {
    "pf_min_samples": 200,
    "pf_max_samples": 2000,
    "laser_max_beams": 30,
    "laser_z_hit": 0.8,
    "laser_z_rand": 0.2,
    "laser_unmodeled_margin": 0.5,
    "odom_alpha1": 0.05,
    "odom_alpha2": 0.05,
    "odom_alpha3": 0.05,
    "odom_alpha4": 0.05,
    "recover_alpha_slow": 0.0,
    "recover_alpha_fast": 0.0,
}
#: what a robot localizing on its sonar ring changes in :data:`AMCL`: its readings are scored by the
#: cone beam model (nav.conebeam), whose predicted range is exact to a cell, and the transducers'
#: noise is 2 cm: a hit's standard deviation of 0.1 m, not the likelihood field's 0.2
#: Its filter is capped at 500 particles, not 2000: on sonar in the thesis crowd the KLD bound asks
#: for the cap all the time (mean 1770-1900 of 2000), and at 500 the accuracy is the same
#: (bench_crowdloc, 30 robots, 30 s, neighbours declared, seeds 0/1/2: within 0.5 m 96.0/97.8/96.3 %
#: at 2000, 95.8/97.7/96.x % at 500) for 0.4-0.6 times the CPU per update.
#: Declared neighbours are landmarks on sonar (known_obstacle_sigma 0.3 m, nav.landmarks): their
#: echoes scored against their bodies, not left out. bench_crowdloc, 30 of the thesis crowd, 80 s,
#: seeds 0-2: 100 % of robot-time within 0.5 m (inner robots, no wall within 5 m: 100 %) against
#: 95.0-98.1 % (inner 88.6-95.6 %) with them left out; CPU per update 7.4-8.8 ms against 4.0-4.7.
AMCL_SONAR: dict = {"laser_sigma_hit": 0.1, "pf_max_samples": 500, "known_obstacle_sigma": 0.3}
#: wavefront: clearance beyond the robot's radius and the global tolerances
WAVEFRONT: dict = {"safety_dist": 0.15, "distance_epsilon": 0.4, "angle_epsilon": 10.0}
#: local planners' goal tolerances, tighter than wavefront's
LOCAL: dict[str, dict] = {
    "vfh": {"distance_epsilon": 0.2, "angle_epsilon": 5.0},
    "nd": {"goal_tol": [0.2, 5.0]},
    "snd": {"goal_position_tol": 0.2, "goal_angle_tol": 5.0},
}
LOCAL_PLANNERS = tuple(LOCAL)
