"""Sample generation: Owen-scrambled Sobol points (:mod:`.sobol`) and the per-lane samplers
of the path tracers (:mod:`.stream`)."""
