"""The signal chain of a survey: analytic signal, matched filter, basebanding, and pulse deconvolution (classic and neural)."""
