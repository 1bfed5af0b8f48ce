"""Hardware protocols: pure codecs (no I/O) and the one serial link the hardware drivers share.

- :mod:`mrs_bridge.hw.p2os`: Pioneer P2OS/ARCOS packets (framing, checksum, commands, SIP parsing);
- :mod:`mrs_bridge.hw.scip`: Hokuyo SCIP 2.0 (frames, check characters, the 6-bit character coding);
- :mod:`mrs_bridge.hw.serial_link`: :class:`SerialLink`, a thread owning a serial port, reconnecting
  with back-off.

The drivers (:mod:`mrs_bridge.drivers.p2os`, :mod:`mrs_bridge.drivers.hokuyo`) are the glue between
a codec, the link and the device server.
"""
