"""The multi-agent layer (the thesis's Jadex role, chapter 3.6.1): agents as peers on Zenoh key spaces."""
