"""Flow control between workers: frame-set assembly, live demand, lossless credits, process supervision.
"""
