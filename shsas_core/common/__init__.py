"""Shared plumbing of every stage: errors, progress and cancellation, device choice, atomic writes, thread pools, heap."""
