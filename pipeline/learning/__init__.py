"""The IK networks of paper 000: model, losses, training loop."""
