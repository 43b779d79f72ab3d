import lerobot_skillret  # noqa: F401  (registers the skillret policy and the panda_kitchen env with LeRobot)
