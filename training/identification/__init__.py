"""Identification of the local model network: OCV pre-fit, tree construction, baselines."""
