"""Pictures of runs: offscreen video, the interactive viewers, the GL backend choice."""
