"""ahrsgen: attitude filters as CasADi equations, emitted as fixed-size C."""
