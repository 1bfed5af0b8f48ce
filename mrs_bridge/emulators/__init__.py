"""Hardware emulators on pseudo-terminals: a Pioneer speaking P2OS/ARCOS (:mod:`.p2os`) and a
Hokuyo URG/UTM speaking SCIP 2.0 (:mod:`.urg`).

Each is written from the manufacturer's published protocol document, with its own tables and
encoders, and imports nothing of the project (not the drivers, not their codecs, not the
simulator): the emulators and the drivers meet only on the wire, so an emulator can catch a
driver's protocol error. Tests drive the drivers against them; ``rsal rehearse``
(:mod:`mrs_bridge.rehearse`) feeds them motion and ranges from a simulated world, so that the real
``p2os`` and ``hokuyo`` drivers serve a "real" robot before the hardware arrives.
"""
