"""canguard's benchmarks: ``python -m benchmarks SUITE [--quick] [--json FILE] [--ab REV]`` (see __main__)."""
