"""Experiments that run the whole offline path: the demo and the paper's experiment."""
