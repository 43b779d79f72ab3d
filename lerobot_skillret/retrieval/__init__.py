"""Retrieval stage: score prior windows by their skill latents' distance to the target's, keep the closest."""
