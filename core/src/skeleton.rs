//! The 13-joint skeleton of DHP19, the joint order of every model, label and simulator array.

/// Joints per pose.
pub const JOINTS: usize = 13;

/// Joint names in DHP19's order, as DHP19's Vicon files (`XYZPOS`) spell its fields.
pub const JOINT_NAMES: [&str; JOINTS] = [
    "head",
    "shoulderR",
    "shoulderL",
    "elbowR",
    "elbowL",
    "hipR",
    "hipL",
    "handR",
    "handL",
    "kneeR",
    "kneeL",
    "footR",
    "footL",
];

/// The skeleton's lines (pairs of joint indices), for drawing.
pub const LINES: [(usize, usize); 14] = [
    (0, 1),
    (0, 2),
    (1, 2),
    (1, 3),
    (3, 7),
    (2, 4),
    (4, 8),
    (1, 5),
    (2, 6),
    (5, 6),
    (5, 9),
    (9, 11),
    (6, 10),
    (10, 12),
];
