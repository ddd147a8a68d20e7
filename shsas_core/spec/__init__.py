"""What a job asks for: the reconstruction spec, its shared options, the method catalogue (torch-free), cost and memory estimates."""
