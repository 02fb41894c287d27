"""Hardware components behind hild's contract: mock, mujoco (the twin), can."""
