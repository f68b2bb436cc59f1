"""Where the step runs. A backend owns the arrays the kernels read (the host State's, or device copies) and runs
the engine's per-item formulae over them: `cpu` (Numba, all threads) and `cuda` (numba.cuda, imported only when
chosen). Both implement the same methods; engine.solver.Solver calls them and nothing else."""
