"""Planning a task: sequential transportation (Algorithm 1), the consistency check, the
receding-horizon replanner."""
