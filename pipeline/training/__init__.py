"""Training and evaluation of the flash classifier.

Only `model` and `trainer` import torch (the optional ``train`` extra); the dataset,
splits, metrics, calibration and baseline modules need numpy/scipy/opencv only, so
``eval-classifier`` and ``classify`` run on a product install.
"""
