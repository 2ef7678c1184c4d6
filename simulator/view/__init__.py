"""The live view (``roger view``): ROGER sessions as Foxglove scenes, images, plots and logs.

Optional: needs the ``foxglove-sdk`` package (``pip install -e '.[live]'``); nothing else in
ROGER imports it.
"""
