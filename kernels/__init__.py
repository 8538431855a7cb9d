"""OpenCL C sources of pydynrad, shipped as package data (see ``pydynrad.device.devices``)."""
