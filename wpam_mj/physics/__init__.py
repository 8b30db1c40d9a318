"""The muscle's physics: parameters, braid geometry, force law and pneumatics.

Nothing here imports from any other sub-package of wpam_mj."""
