"""What the tests and the benchmarks share, and neither owns: starting servers, aiortc
viewers, the link emulator, protocol and policy clients, hand-built recordings, the
simulated cell in virtual time. Helpers, not benchmarks (they print no figures); in a
checkout only, never in the wheel. Imports the product, never bench/ or tests/."""
