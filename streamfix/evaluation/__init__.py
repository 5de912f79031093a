"""Evaluation protocols (the papers' experiments on our data): corrupt ground truth, clean, score."""
