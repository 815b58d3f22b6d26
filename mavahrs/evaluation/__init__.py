"""Evaluation against ground truth: metrics, dataset loaders, studies, tuning, plots."""
