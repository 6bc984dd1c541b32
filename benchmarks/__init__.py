"""benchmarks (folder benchmarks/, run as `python -m benchmarks`): simrun's timing benchmarks, outside the test suite."""
