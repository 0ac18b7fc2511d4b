"""The simulated Feetech servo bus: a product feature, not only a test fake."""
