"""Training the network on projsynth shards: the torch dataset and augmentation, the loss, the training
loop with checkpoints and resume, ``torchrun`` ranks, and the validation it runs.
"""
