"""The differential-drive robot pack: module types of ``architectures/diffdrive.yaml``.

A pack is an ordinary plugin that ships with archself: its types reach the core
only through the ``archself.modules`` entry-point group (see ``pyproject.toml``),
exactly like a third party's. The core never imports this package.

==========================  =====================================================
type key                    class
==========================  =====================================================
plant.diffdrive             :class:`~archself_diffdrive.physical.DiffDrivePlant`
actuator.wheel              :class:`~archself_diffdrive.physical.WheelActuator`
sensor.encoders             :class:`~archself_diffdrive.physical.WheelEncoders`
sensor.imu                  :class:`~archself_diffdrive.physical.Imu`
sensor.gps                  :class:`~archself_diffdrive.physical.Gps`
planner.spline              :class:`~archself_diffdrive.planner.SplinePlanner`
estimator.odometry          :class:`~archself_diffdrive.estimators.Odometry`
estimator.ekf               :class:`~archself_diffdrive.estimators.Ekf` (closed form)
controller.lqr              :class:`~archself_diffdrive.controllers.LqrController` (python-control)
controller.asym_lqr         :class:`~archself_diffdrive.controllers.AsymLqrController`
model.diffdrive_kinematics  :class:`~archself_diffdrive.models.DiffDriveKinematicsModel`
model.diffdrive_dynamics    :class:`~archself_diffdrive.models.DiffDriveDynamicsModel`
model.actuator              :class:`~archself_diffdrive.models.ActuatorModel`
==========================  =====================================================
"""
