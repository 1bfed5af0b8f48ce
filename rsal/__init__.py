"""RSAL, the Robot System Abstraction Layer (thesis 3.6.2): data types, device proxies, DeviceNode,
robots and behaviours, between the agents and the device servers."""
