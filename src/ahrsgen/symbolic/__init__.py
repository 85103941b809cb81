"""CasADi SX building blocks shared by the filters (no filter imports here)."""
