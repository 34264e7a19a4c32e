"""Sensor side of the imaging simulation: validated sensor profiles (geometry, colour,
noise), the spectral response (spectral), colour calibration and the ISP stages
(unprocess, mosaic, noise, demosaic, process)."""

from lensim.sensor.profile import DEFAULT_SENSOR, SensorProfile, load_sensor, sensor_from_dict, sensor_names

__all__ = ["DEFAULT_SENSOR", "SensorProfile", "load_sensor", "sensor_from_dict", "sensor_names"]
