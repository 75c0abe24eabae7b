"""Torch-free inference of the learned policies: checkpoints read without torch (ptfile), the
features (tokens), the layers and networks in numpy (layers, nets) and the acting policy
(policy). Robot processes import only this; the torch networks in policies/ train the weights.
"""
