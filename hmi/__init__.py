"""plchmi: an operator HMI and soft-PLC runtime (README.md; the layers: docs/architecture.md)."""
