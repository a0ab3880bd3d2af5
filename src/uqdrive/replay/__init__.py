"""A recorded failing rollout driven again, exactly, and written as a video."""
