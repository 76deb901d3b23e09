"""Pipeline stages, one module per stage, each owning its kernels."""
