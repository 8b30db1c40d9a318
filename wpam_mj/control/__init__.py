"""The external-pressure controllers and the Pi feedforward."""
