"""Cover stage: R → the covering model (S or V), and the set cover solved on it (SPEC §3–4).

density (δ, S, V, uncoverable faces), problem (input checks, tolerance), greedy, reduce (exact
reductions), lpbound (LP and Lagrangian bounds), mip (HiGHS in a child process), rowweight
(row-weighting local search), setcover (the driver), partial (a fraction of the area), orlib
(OR-Library reader). Works on matrices: imports only the shared leaves, never a mesh.
"""
