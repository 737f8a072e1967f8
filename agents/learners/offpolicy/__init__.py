"""The off-policy learners TD3 and DroQ: their driver, replay, observer and updates."""
