"""``plchmi soak``: the whole HMI driven by a seeded random operator, invariants checked after
every step (hmi.soak.runner, hmi.soak.operator, hmi.soak.invariants, hmi.soak.steps)."""
