"""Online anchor selection (Section 4): heuristic seed, Monte Carlo e_l, genetic inner loop, outer loop."""
