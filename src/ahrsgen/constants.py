"""Physical constants shared by models and references (same values as ahrsgen.sim.log)."""
G0 = 9.80665  # standard gravity, m/s^2
