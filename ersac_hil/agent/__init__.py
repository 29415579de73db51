"""The robot-side agent: CANopen master, policies, LQR balance, cost terms, episodes, service."""
