"""The physical world: plants, the sensor chain, the lockstep clock, scenarios, traces and metrics."""
