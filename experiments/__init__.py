"""Experiments that reproduce the paper's tables (python -m experiments.ablation)."""
