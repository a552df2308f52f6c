"""Does the classifier add substance information beyond the substance network on exemplars?"""
