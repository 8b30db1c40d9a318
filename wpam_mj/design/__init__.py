"""Design studies: parameter studies over many runs, and linear models for controller design."""
