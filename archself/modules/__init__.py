"""Built-in module library; importing this package registers every built-in type.

Heavy libraries (python-control, filterpy) are imported inside the classes that
use them, so importing the library stays cheap for ``archself validate``.

==========================  ==============================================
type key                    class
==========================  ==============================================
plant.diffdrive             :class:`~archself.modules.physical.DiffDrivePlant`
actuator.wheel              :class:`~archself.modules.physical.WheelActuator`
sensor.encoders             :class:`~archself.modules.physical.WheelEncoders`
sensor.imu                  :class:`~archself.modules.physical.Imu`
sensor.gps                  :class:`~archself.modules.physical.Gps`
planner.spline              :class:`~archself.modules.planner.SplinePlanner`
estimator.odometry          :class:`~archself.modules.estimators.Odometry`
estimator.ekf               :class:`~archself.modules.estimators.Ekf`
controller.lqr              :class:`~archself.modules.controllers.LqrController`
controller.asym_lqr         :class:`~archself.modules.controllers.AsymLqrController`
model.diffdrive_kinematics  :class:`~archself.modules.models.DiffDriveKinematicsModel`
model.diffdrive_dynamics    :class:`~archself.modules.models.DiffDriveDynamicsModel`
model.actuator              :class:`~archself.modules.models.ActuatorModel`
==========================  ==============================================
"""

from archself.modules import (  # noqa: F401
    base,  # noqa: F401
    controllers,
    estimators,
    generic,  # noqa: F401
    models,
    physical,
    planner,
    process,  # noqa: F401
)
