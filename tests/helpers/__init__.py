"""Data builders and small oracles shared by the test packages."""
