"""Browser tests: the HMI in headless Chromium against ``lupin run --sim``."""
