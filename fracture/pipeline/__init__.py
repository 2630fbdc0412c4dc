"""The experiment pipeline: configs and their schema, the runner and its stages, the stage cache and
sweeps."""
