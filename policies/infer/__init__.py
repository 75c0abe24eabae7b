"""Torch-free inference of the learned policies: checkpoints read without torch (ptfile), the
features (tokens), the layers and networks in numpy (layers, nets) and the acting policy
(policy), over policies.base, belief, checkpoint and grid_search (and a model's hint planner:
chain-plan, central or team-beam); none imports torch, so a robot process acts with this alone
while the torch networks in policies/ train the weights.
"""
