"""Image formation from signals: time-domain backprojection (with its kernels as private modules), quick looks, planar focus, autofocus."""
