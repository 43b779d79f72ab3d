"""Data stage: LeRobotDataset episodes -> memory-mapped TensorDict columns -> sub-trajectory windows.

Also the files that stages exchange: dataset and checkpoint fingerprints, the retrieval file (written by retrieval,
read by the policy) and the optional per-frame primitive labels that retrieval reports score against.
"""
