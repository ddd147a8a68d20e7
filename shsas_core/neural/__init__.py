"""The neural scattering field (SH-SAS and Reed et al.): fields, the differentiable renderer, training, warm start."""
