"""Linear models of the nonlinear plant: describing functions, small-signal models, sampled-data models, uncertainty."""
