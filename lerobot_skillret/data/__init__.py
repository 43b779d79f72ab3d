"""Data stage: LeRobotDataset episodes -> memory-mapped TensorDict columns -> sub-trajectory windows."""
