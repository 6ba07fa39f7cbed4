"""What ``skinloc bench`` runs: the paper's experiment and the live path's benchmarks."""
