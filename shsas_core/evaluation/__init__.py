"""From volume to geometry and scores: extraction (ridge + mesh), metrics, alignment, result diagnostics."""
