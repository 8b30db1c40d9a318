"""The muscle's physics: parameters, muscle types, braid geometry, force law and pneumatics.

Nothing here imports from the other sub-packages of wpam_mj, only the base modules (the
paper's numbers, units, paths): a reader checks the physics by reading this package alone
(tests/test_layout.py holds it).
"""
