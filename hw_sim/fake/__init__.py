"""The parts of hw_sim's Picamera2 fake, by concern (the public names are in hw_sim.picamera2_fake).

sensors   the sensor-mode tables, SensorFormat, Transform
world     SimWorld (the run, its clock and ground truth) and ManualClock
crop      libcamera's integer ScalerCrop arithmetic
configs   picamera2's configuration dicts and their checks
camera    FakePicamera2 and make_picamera2
request   CompletedRequest and MappedArray
"""
