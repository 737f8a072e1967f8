"""Controllers that learn nothing: SPGD-PID, the physics-informed fit, the trim, the stall
escape."""
