"""Training the learned backends: datasets of synthetic and real frames, the training loop."""
