"""Learning and control environments: dm_env, Gymnasium, vectorised, reference policies."""
