"""fohssv_sim: the FO-HSSV model library (pure) and its ROS 2 nodes (in ``ros/``)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version('fohssv_sim')
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = '0.1.0'
