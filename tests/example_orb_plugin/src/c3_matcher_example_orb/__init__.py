"""Example c3-matcher plugin: ORB + brute-force Hamming matching (no ONNX)."""
