//! The configurations `bench` times, and the peer each is divided by.

/// What a configuration sweeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Workload {
    /// A synthetic row of cameras with the paper's settings (best half-sequence, shiftable 2x2
    /// windows, per-pair aggregation).
    Paper,
    /// A synthetic row of cameras with the engine defaults (AD-census, best half-sequence,
    /// centred 5x5, SGM, coarse to fine), as a live node would run.
    Defaults,
    /// The demo: the built-in Tsukuba set (5 views 384x288, 32 planes) with its defaults.
    Demo,
    /// Converging cameras on an arc (general poses, as the rings, ICL-NUIM or a capture rig
    /// whose images are not rectified) with the engine defaults; `distorted`: every camera
    /// with a mild plumb-bob barrel, as a driver's raw images.
    Ring { distorted: bool },
    /// Two cameras side by side (the stereo camera most ROS users have) with the engine
    /// defaults: rectified, or (`distorted`) raw images with a plumb-bob barrel and a slight
    /// toe-in, as a driver's `image_raw`.
    Pair { distorted: bool },
    /// A capture dome: cameras on a 35-degree spherical cap around a point 4 m ahead of the
    /// reference (at the cap's pole), all looking at it, with the engine defaults; the
    /// reference sweeps with the views chosen for it (`geometry::neighbours`).
    Dome,
}

/// What a configuration's time is divided by, measured just before and after it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PeerKind {
    /// OpenCV StereoSGBM 3-way on two Tsukuba views, 32 disparities.
    Tsukuba,
    /// What a ROS user runs on a stereo camera of the configuration's size: StereoSGBM 3-way
    /// with the configuration's planes as disparities, after (`rectify`) image_geometry's
    /// rectification of both raw views (cv2.remap with maps made once).
    Pair { rectify: bool },
}

/// One benchmark configuration.
#[derive(Debug, Clone, Copy)]
pub struct BenchConfig {
    pub name: &'static str,
    pub cameras: usize,
    pub width: u32,
    pub height: u32,
    pub planes: u32,
    pub workload: Workload,
    /// Several references per set (`references`, camera indices); empty: the rig's middle
    /// camera alone, as a plain sweep.
    pub references: &'static [usize],
    /// `max_neighbours` (0: every camera that sees the reference's view).
    pub max_neighbours: u32,
    pub peer: PeerKind,
}

/// The configurations.
pub const CONFIGS: [BenchConfig; 14] = [
    BenchConfig {
        name: "paper",
        cameras: 4,
        width: 320,
        height: 240,
        planes: 20,
        workload: Workload::Paper,
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "demo",
        cameras: 5,
        width: 384,
        height: 288,
        planes: 32,
        workload: Workload::Demo,
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "9-camera",
        cameras: 9,
        width: 450,
        height: 375,
        planes: 57,
        workload: Workload::Defaults,
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    // The 9-camera rig with three references (cameras 1, 4 and 7: depth across the row): with
    // every camera each, and with each reference's nearest two on each side
    // (`max_neighbours` 4: the 4 best views by triangulation angle, two on each side; the
    // name is from when they were the nearest). Beside "9-camera" (the middle camera alone, all 8 others) and
    // "9-camera-near4" (the middle camera alone with its 4 nearest).
    BenchConfig {
        name: "9-camera-near4",
        cameras: 9,
        width: 450,
        height: 375,
        planes: 57,
        workload: Workload::Defaults,
        // The middle camera as a reference (`run_references`: neighbours chosen).
        references: &[4],
        max_neighbours: 4,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "9-camera-3refs",
        cameras: 9,
        width: 450,
        height: 375,
        planes: 57,
        workload: Workload::Defaults,
        references: &[1, 4, 7],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "9-camera-3refs-near4",
        cameras: 9,
        width: 450,
        height: 375,
        planes: 57,
        workload: Workload::Defaults,
        references: &[1, 4, 7],
        max_neighbours: 4,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "vga",
        cameras: 4,
        width: 640,
        height: 480,
        planes: 64,
        workload: Workload::Paper,
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "ring",
        cameras: 5,
        width: 640,
        height: 480,
        planes: 96,
        workload: Workload::Ring { distorted: false },
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "ring-distorted",
        cameras: 5,
        width: 640,
        height: 480,
        planes: 96,
        workload: Workload::Ring { distorted: true },
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "sxga",
        cameras: 4,
        width: 1280,
        height: 960,
        planes: 128,
        workload: Workload::Paper,
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    // Issue 52: a stereo camera, rectified (an ETH3D pair's size) and raw (a 752x480 global
    // shutter camera with plumb_bob lenses), each beside rectification + SGBM at its size.
    BenchConfig {
        name: "stereo-rect",
        cameras: 2,
        width: 940,
        height: 490,
        planes: 32,
        workload: Workload::Pair { distorted: false },
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Pair { rectify: false },
    },
    BenchConfig {
        name: "stereo-raw",
        cameras: 2,
        width: 752,
        height: 480,
        planes: 96,
        workload: Workload::Pair { distorted: true },
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Pair { rectify: true },
    },
    // Issue 53: a dome of 32 cameras (the reference takes 8 views, `max_neighbours` 0) beside
    // one of 8 on the same cap (all 7 others): the time per reference follows the views used,
    // not the cameras in the rig.
    BenchConfig {
        name: "dome-8",
        cameras: 8,
        width: 640,
        height: 480,
        planes: 64,
        workload: Workload::Dome,
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
    BenchConfig {
        name: "dome-32",
        cameras: 32,
        width: 640,
        height: 480,
        planes: 64,
        workload: Workload::Dome,
        references: &[],
        max_neighbours: 0,
        peer: PeerKind::Tsukuba,
    },
];
