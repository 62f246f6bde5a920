"""Evaluation: free-run simulation, metrics, observers on records, FMU-vs-pipeline checks."""
