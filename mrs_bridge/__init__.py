"""The Player-style device server: drivers that provide and require devices on the Zenoh key space."""
