"""Plants: the contract (base.py), simulated plants (sim/), real ones over Modbus (modbus/).

Modules moved here by issue 14 keep their old names for one phase (hmi.moved).
"""
