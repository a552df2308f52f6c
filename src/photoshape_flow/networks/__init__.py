"""Trained networks as the stages after training read them: which classifier, loaded how, its stored
calibrations, and the validation renders and photo degradation they share. No stage entry here.
"""
