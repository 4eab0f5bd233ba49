"""Files gltrack generates or authors (the part classifier), shipped as the package ``gltrack.assets``.

Find them with :func:`gltrack.asset_path`.
"""
