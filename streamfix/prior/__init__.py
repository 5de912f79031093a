"""The learned motion prior: temporal-convolution autoencoder (Lohit et al.) run with onnxruntime."""
