"""PPO and SAC: brax.training's trainers on the Brax adapter."""
