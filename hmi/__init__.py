"""plchmi: an operator HMI and soft-PLC runtime (README.md; the layers: docs/architecture.md)."""

from hmi import moved

moved.install()  # old module names of issue 14's moves, for one phase
