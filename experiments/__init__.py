"""Accuracy research: one package per question, each run as a module (`python -m experiments.<question>.run`)."""
