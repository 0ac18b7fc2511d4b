"""The browser HMI: static HTML, CSS and JavaScript served by the API at ``/`` and ``/static/``.

No build step: the files in ``static/`` are shipped as package data and read
through :mod:`importlib.resources`, so the HMI works from a wheel as from a checkout.
"""
