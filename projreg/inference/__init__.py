"""Applying the network to pairs: runtimes (PyTorch, onnxruntime), ``predict``, tracking a sequence,
compensation (geometric and photometric), the ONNX export and the files these commands write.
"""
