"""Controller design against the linearized plant family: loop shaping, H-infinity, margins."""
