"""ROS 2 over Zenoh: the fleet in ROS 2 tools through rmw_zenoh's wire, without a ROS installation.

``wire`` holds rmw_zenoh's keys, attachment, QoS strings and graph tokens; ``types`` the message
types, their RIHS01 hashes, CDR and the builders from RSAL data; ``rmw`` nodes, publishers and
subscriptions on a Zenoh session; ``export`` the exporter behind ``rsal ros2`` (``cli``) and the
``ros2_export`` driver (``export_driver``), with ``fleet`` for ``/map`` and ``/clock``; ``driver``
the ``ros2`` import driver of ``rsal serve``; ``bag`` ``rsal rosbag2``. What maps to what:
``docs/ros2.md``.
"""
