"""One reconstruction job, end to end: the loop the CLI and the worker call, and its resume bookkeeping."""
