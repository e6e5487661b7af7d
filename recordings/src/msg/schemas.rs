//! The `ros2msg` schema of each message: its definition followed by every nested type's,
//! separated by a line of 80 `=`, as `ros2 bag` and Foxglove read them from an MCAP file.

use super::{
    AckermannDriveStamped, LaserScan, Odometry, PoseStamped, PoseWithCovarianceStamped, RosMessage,
    TFMessage,
};

macro_rules! schema {
    ($main:expr $(, $dep:expr)*) => {
        concat!($main $(, sep!(), $dep)*)
    };
}

/// The line between a ros2msg schema's definitions.
macro_rules! sep {
    () => {
        "================================================================================\n"
    };
}

/// The definitions every stamped message depends on: Header, then Time.
macro_rules! header_defs {
    () => {
        concat!(
            "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n",
            sep!(),
            "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
        )
    };
}

/// geometry_msgs/PoseWithCovariance and the definitions it depends on.
macro_rules! pose_with_covariance_defs {
    () => {
        concat!(
            "MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance\n",
            sep!(),
            "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
            sep!(),
            "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n",
            sep!(),
            "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"
        )
    };
}

impl RosMessage for LaserScan {
    const PACKAGE: &'static str = "sensor_msgs";
    const TYPE: &'static str = "LaserScan";
    const SCHEMA: &'static str = schema!(
        "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\nfloat32 time_increment\nfloat32 scan_time\nfloat32 range_min\nfloat32 range_max\nfloat32[] ranges\nfloat32[] intensities\n",
        header_defs!()
    );
}

impl RosMessage for Odometry {
    const PACKAGE: &'static str = "nav_msgs";
    const TYPE: &'static str = "Odometry";
    const SCHEMA: &'static str = schema!(
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
        header_defs!(),
        pose_with_covariance_defs!(),
        "MSG: geometry_msgs/TwistWithCovariance\ngeometry_msgs/Twist twist\nfloat64[36] covariance\n",
        "MSG: geometry_msgs/Twist\ngeometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
        "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
    );
}

impl RosMessage for AckermannDriveStamped {
    const PACKAGE: &'static str = "ackermann_msgs";
    const TYPE: &'static str = "AckermannDriveStamped";
    const SCHEMA: &'static str = schema!(
        "std_msgs/Header header\nackermann_msgs/AckermannDrive drive\n",
        header_defs!(),
        "MSG: ackermann_msgs/AckermannDrive\nfloat32 steering_angle\nfloat32 steering_angle_velocity\nfloat32 speed\nfloat32 acceleration\nfloat32 jerk\n"
    );
}

impl RosMessage for PoseWithCovarianceStamped {
    const PACKAGE: &'static str = "geometry_msgs";
    const TYPE: &'static str = "PoseWithCovarianceStamped";
    const SCHEMA: &'static str = schema!(
        "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n",
        header_defs!(),
        pose_with_covariance_defs!()
    );
}

impl RosMessage for PoseStamped {
    const PACKAGE: &'static str = "geometry_msgs";
    const TYPE: &'static str = "PoseStamped";
    const SCHEMA: &'static str = schema!(
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
        header_defs!(),
        "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
        "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n",
        "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"
    );
}

impl RosMessage for TFMessage {
    const PACKAGE: &'static str = "tf2_msgs";
    const TYPE: &'static str = "TFMessage";
    const SCHEMA: &'static str = schema!(
        "geometry_msgs/TransformStamped[] transforms\n",
        "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
        header_defs!(),
        "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
        "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n",
        "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"
    );
}
