"""Maps: building them from recordings, the ROS map_server file format, and map tools."""
