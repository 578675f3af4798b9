"""Thresholds of the vision stage, each with its default and the reason for it."""

from __future__ import annotations

from dataclasses import dataclass, replace

from softforce_cli.vision.decimation import MAX_DECIMATION, decimation_factor

# The longest distance a vision setting may give (mm): beyond the 1.5 m a D415 sees a soft
# robot from, where match_search_mm's line samples would no longer fit in memory.
MAX_LENGTH_MM = 1500.0
# The brightest shade of the learned robot colour robot_max_shade may allow: 255 levels in
# each channel are at most 10 times a colour learned at a tenth of them.
MAX_SHADE = 10.0
# The widest bleed edge_bleed_px may look for: a stereo window's half width at most
MAX_EDGE_BLEED_PX = 8


@dataclass(frozen=True)
class VisionSettings:
    """Every threshold of the vision stage (lengths in mm, colours in RGB levels 0-255).

    Filtering (the paper's PassThrough, VoxelGrid, RadiusOutlier; its camera code's values):
    voxel_mm               : 1.1, the VoxelGrid leaf. At 0.5-0.6 m a D415 pixel spans
                             0.8-1.3 mm, so this keeps about one point per pixel footprint and
                             mostly removes duplicates where the surface is steep.
    outlier_radius_mm      : 5.0, RadiusOutlier radius.
    outlier_min_neighbours : 20, points with fewer neighbours (itself excluded) within the
                             radius are removed: a surface patch of radius 5 mm holds about 60
                             points at 1.1 mm spacing, an isolated speckle a handful. 0 turns
                             the filter off (region growing still drops isolated specks).
    crop_margin_mm         : 40.0, the PassThrough box is the model's current bounds grown by
                             this on every side: room for deformation the model has not yet
                             followed and for the objects touching the robot, long enough of
                             them to show an axis (occluded_tip_mm): with 20 mm a probe
                             pressing the apex 25 degrees from the vertical left 26 points
                             in the box, no axis, and was missed (docs/sensing_studies.md,
                             "Large deformations"). The box's object points grow by a fifth,
                             its time by 0.3 ms a frame.

    Table removal (not in the paper; its figures show the robot on a table that would
    otherwise become one large "object" touching the robot's base):
    table_slab_mm          : 30.0, the table plane is fitted to points less than this above
                             the model's lowest point (the robot stands on the table).
    table_fit_mm           : 4.0, RANSAC inlier distance, about 2 sigma of D415 depth noise at
                             0.6 m at 424x240 (1.8 mm) and 3 sigma at 640x480 (1.2 mm).
    table_clearance_mm     : 8.0, points closer than this to the fitted plane (or below it)
                             are table: over 4 sigma of depth noise, and still inside the
                             Diamond's clamped base (the clamp reaches 47 mm above the table),
                             so no robot point that matters is lost.
    table_min_points       : 200, fewer points in the slab than this: no table in view, none
                             removed (pipeline.process_frame fits the table on every third
                             pixel row and column, and asks a ninth of this there).

    Colour region growing (as PCL's RegionGrowingRGB):
    region_neighbour_mm    : 3.0, two points are neighbours when closer than this: about two
                             point spacings at 424x240 (1.6 mm at 0.5 m), so a surface stays
                             connected under depth noise, while surfaces 3 mm apart do not.
    point_colour_threshold : 30.0, neighbours join one region when their colours differ by
                             less than this (Euclidean RGB): colour noise (2 levels per channel,
                             so about 5 between two points) and smooth shading stay inside,
                             edges between different paints (distance > 100) do not.
    region_colour_threshold: 40.0, neighbouring regions whose mean colours differ by less are
                             merged (PCL's region merging): one surface split by a shading
                             gradient or a dark seam becomes one region again.
    region_hue_deg         : 6.0, in both steps two colours must also point within this
                             angle of each other in RGB, or within what the camera's colour
                             noise (2 levels a channel, 3 sigma) turns colours that dark: 14
                             degrees between two points at 35 levels. Under a lamp the
                             Euclidean thresholds join what the shade brings close: a probe's
                             shaded side to the robot's (38 levels apart, 70 degrees), a skin
                             probe's to a white robot's shadow (29 levels, 8.5 degrees); 10
                             degrees left the latter joined, 20 too (docs/vision.md,
                             "Lighting"). 0 turns it off.
    min_region_points      : 10, smaller regions merge into the neighbouring region they share
                             most neighbour pairs with, or are dropped when isolated (PCL's
                             minimum cluster size).
    robot_colour_tolerance : 70.0, a region belongs to the robot when its mean colour is this
                             close to the robot colour. Shading darkens a surface to 0.7 of its
                             colour at grazing incidence ([40, 90, 210] -> [28, 63, 147] is at
                             70); other paints in the sample scenes lie 170 or more away.
    robot_hue_deg          : 5.0, a region belongs to the robot too when its mean colour is
                             the robot's shaded: a white light scales the three channels alike,
                             so the colour points the robot colour's way in RGB (within this
                             angle) at robot_min_shade to robot_max_shade times its brightness.
                             A lamp beside the robot leaves the faces it does not reach and the
                             probe's shadow at 0.4 of the learned colour, 98 levels from it,
                             within 0.6 degrees of its direction; the sample scenes' other
                             paints lie 33 (a grey), 45 (the table) and 66 (the probes) degrees
                             away, a skin probe 8.5 degrees from a white robot (10 took it for
                             the robot under a lamp; docs/vision.md, "Lighting"). So is the
                             robot colour shaded under a white highlight (within this angle of
                             the plane it spans with white, segmentation._highlighted). 0
                             turns both off.
    robot_min_shade        : 0.25, the darkest shade of the robot colour taken for the robot
                             by its direction (near black, a colour's direction is noise).
    robot_max_shade        : 2.0, the brightest (the colour is learned on the first frame).

    edge_bleed_px          : 2, within this many pixels of a depth edge deeper than
                             edge_jump_mm, a pixel on either side whose colour is the other
                             side's (by point_colour_threshold) carries a depth that bled or a
                             colour registered off it, and is dropped before the cloud is made
                             (vision.depth_edges): two pixels of either turned the probe's
                             outline into the robot's and gave contacts up the probe
                             (docs/vision.md, "Edges"). 0 turns it off.
    edge_jump_mm           : 10.0, the depth step that makes an edge: over 4 sigma of the
                             D415's noise at 0.6 m, under a probe's rod above the skin.
    rim_mm                 : 4.0, a region not of the robot's colour none of whose points lies
                             further than this from a robot point is the robot's own rim seen
                             in another colour, and no object: a depth camera bleeds the nearer
                             depth a pixel or two past an edge (the stereo window's edge
                             fattening), a colour image registered a pixel off the depth paints
                             the edge in the background's colour, a marker sticker lies on the
                             skin. Two pixels of bleed at 640x480 and 0.54 m left such rims up
                             to 3.3 mm from the robot; a probe's region reaches 10 mm and more
                             (docs/vision.md, "Edges"). 0 turns it off.

    Contacts (Algorithm 2):
    contact_radius_mm      : 4.0, r_search (the paper's camera code).
    contact_min_neighbours : 3, n_neigh: an object point with MORE than this many robot points
                             within r_search is a contact point.
    cluster_tolerance_mm   : 5.0, Euclidean clustering distance (the paper's camera code).
    cluster_min_points     : 1, smaller clusters are dropped. One is enough: a contact point
                             already belongs to an object region of min_region_points that
                             survived the outlier filter, and a probe pressing on a side the
                             camera does not see leaves only one to five contact points at
                             640x480 (the sample probe on the east elbow: one).
    contact_merge_mm       : 10.0, clusters whose centres are closer than this are one contact
                             (at their point-weighted mean): a 10 mm probe's tip patch seen
                             through depth noise splits into clusters 6-8 mm apart
                             (benchmarks/scenarios/other_actuation.toml), each of which would
                             get a force column of its own; two objects that close are not
                             told apart by the feature points anyway (10-15 mm apart with
                             151). 0 keeps every cluster (the paper).
    contact_exclusion_mm   : 5.0, contact points within this of the clamped region's box
                             (given by the caller) are ignored: a clamp or fixture touching
                             the base exerts no force the model can explain.
    occluded_tip_mm        : 10.0, an elongated object (a rod, a finger) none of whose points
                             is a contact point touches the robot where its axis, extended
                             by at most this beyond its end nearer the robot, passes within
                             contact_radius_mm of MORE than contact_min_neighbours robot
                             points (contacts.occluded_tips): a rod tilted from the view
                             hides its own tip, and its line meets a face it presses
                             obliquely 8-10 mm beyond its last seen point (8 until
                             2026-12-01: the apex probe above met the robot 7.6-8.5 mm
                             beyond, a 424x240 elbow probe was missed on one frame). 0 turns
                             this off (Algorithm 2 alone).

    Feature matching (Algorithm 3):
    match_line_mm          : 4.0, d_m: a feature is hidden when no robot point lies within
                             this of its normal line (the paper's camera code).
    match_limit_mm         : 20.0, d_l: a match further than this from its feature is taken as
                             mis-segmented. A 0.6 N probe moves the Diamond's upper bar by
                             16 mm, so smaller would reject real deformation.
    match_search_mm        : 30.0, candidates are the robot points within this of the feature,
                             not the whole cloud: the normal line through one arm crosses the
                             other arms or the apex 50-200 mm away (the paper's Fig. 3 shows
                             the search near the feature). Larger than d_l so that a match
                             beyond d_l is seen and rejected rather than silently missed.
    match_mean_mm          : 2.0, the observed point is the mean of the robot points within
                             this of the normal line (and within d_m along it of the nearest
                             one), not the paper's single nearest point, which jumps by up to
                             1 mm between noise-free frames as holes and colour noise change
                             which pixel is nearest. Measured on eleven recordings of the
                             studies (docs/sensing_studies.md, "Averaging the matched points,
                             with edge-on features hidden"): the median intensity error 11%
                             lower summed over them, the 12-location probes 8.5% /
                             17.8% (median / 90th pct) on the 6.5 mm truth (8.3% / 16.4%
                             with the nearest point) and 6.4% / 20.5% on the converged body
                             (8.0% / 24.7%); a camera 753 mm away 8.7% / 26.1% (7.1% /
                             11.3%). 0: the nearest point.
    match_max_view_deg     : 75.0, a feature whose normal is further than this from the line
                             of sight to the camera is seen nearly edge-on: its face is
                             sampled sparsely (the D415 drops pixels beyond about 78
                             degrees), and the line along its normal can meet the opposite
                             face of a thin part first. An oblique camera had features under
                             the Diamond's bars matched on the bars' top faces 16-20 mm
                             inward (a tare frame fitted 4.3 mm RMS); with averaged matches,
                             frames without contact fitted 3-4.8 mm and a 0.25 N probe read
                             0 N. 90: no feature is taken as edge-on.
    match_grazing_mm       : 8.0, such a feature is hidden unless its observed point lies
                             within this of it along its normal: on the oblique camera 3, 5
                             and 8 mm read alike; a robot seen from the side keeps its flanks
                             (the hanging trunk of docs/sensing_studies.md: 4.1% / 7.6%
                             median / 90th pct, 7.7% / 16.2% with every edge-on feature
                             hidden).

    Other cameras:
    decimation             : 0 (automatic): the frame's pixels are taken in k x k blocks
                             (decimation.decimate_frame) with k = round(voxel_mm / pixel
                             footprint) at the robot's distance: 2 for a 1280x720 D415 at
                             0.5-0.6 m, whose pixels span half a leaf, 1 (every pixel) for
                             848x480 and below. A finer image costs three to four times as
                             much in the radius searches for a surface the feature points
                             do not need finer (docs/vision.md, "Other resolutions"). 1
                             keeps every pixel; k >= 2 (at most 8) forces k.
    scale_to_camera        : True, the neighbour counts above (outlier_min_neighbours,
                             contact_min_neighbours) are those of a 640x480 D415, the paper's
                             camera; pipeline.process_frame scales them to the frame's camera
                             (its focal length after decimation and its distance to the
                             robot) with settings_for_camera. False uses them as given.
    """

    voxel_mm: float = 1.1
    outlier_radius_mm: float = 5.0
    outlier_min_neighbours: int = 20
    crop_margin_mm: float = 40.0
    table_slab_mm: float = 30.0
    table_fit_mm: float = 4.0
    table_clearance_mm: float = 8.0
    table_min_points: int = 200
    region_neighbour_mm: float = 3.0
    point_colour_threshold: float = 30.0
    region_colour_threshold: float = 40.0
    region_hue_deg: float = 6.0
    min_region_points: int = 10
    robot_colour_tolerance: float = 70.0
    robot_hue_deg: float = 5.0
    robot_min_shade: float = 0.25
    robot_max_shade: float = 2.0
    rim_mm: float = 4.0
    edge_bleed_px: int = 2
    edge_jump_mm: float = 10.0
    contact_radius_mm: float = 4.0
    contact_min_neighbours: int = 3
    cluster_tolerance_mm: float = 5.0
    cluster_min_points: int = 1
    contact_merge_mm: float = 10.0
    contact_exclusion_mm: float = 5.0
    occluded_tip_mm: float = 10.0
    match_line_mm: float = 4.0
    match_limit_mm: float = 20.0
    match_search_mm: float = 30.0
    match_mean_mm: float = 2.0
    match_max_view_deg: float = 75.0
    match_grazing_mm: float = 8.0
    decimation: int = 0
    scale_to_camera: bool = True

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            may_be_zero = ("contact_min_neighbours", "outlier_min_neighbours", "scale_to_camera",
                           "match_mean_mm", "occluded_tip_mm", "decimation", "robot_hue_deg",
                           "region_hue_deg", "rim_mm", "edge_bleed_px")
            if name not in may_be_zero and not value > 0:
                raise ValueError(f"vision setting {name} must be positive, got {value}")
            if name in may_be_zero and not value >= 0:
                raise ValueError(f"vision setting {name} must be >= 0, got {value}")
            # a length beyond the scene (or infinite) sizes arrays the machine cannot hold
            if name.endswith("_mm") and not value <= MAX_LENGTH_MM:
                raise ValueError(f"vision setting {name} must be at most {MAX_LENGTH_MM:g} mm, "
                                 f"got {value}")
        if self.edge_bleed_px not in range(MAX_EDGE_BLEED_PX + 1):
            raise ValueError(f"vision setting edge_bleed_px must be a whole number from 0 "
                             f"(off) to {MAX_EDGE_BLEED_PX}, got {self.edge_bleed_px}")
        if self.decimation not in range(MAX_DECIMATION + 1):
            raise ValueError(f"vision setting decimation must be a whole number from 0 "
                             f"(automatic) to {MAX_DECIMATION}, got {self.decimation}")
        for name in ("robot_hue_deg", "region_hue_deg"):
            if not 0.0 <= getattr(self, name) < 90.0:
                raise ValueError(f"vision setting {name} must be from 0 (off) to below 90, "
                                 f"got {getattr(self, name)}")
        if not self.robot_min_shade <= 1.0 <= self.robot_max_shade <= MAX_SHADE:
            raise ValueError("vision settings robot_min_shade and robot_max_shade must bracket "
                             f"1 (the learned colour), at most {MAX_SHADE:g}, got "
                             f"{self.robot_min_shade} and {self.robot_max_shade}")
        if not self.match_max_view_deg <= 90.0:
            raise ValueError("vision setting match_max_view_deg must be at most 90 (a face "
                             f"seen from behind is never matched), got {self.match_max_view_deg}")
        if self.match_search_mm < self.match_limit_mm:
            raise ValueError("vision setting match_search_mm must be at least match_limit_mm")


# fx of the 640x480 D415 colour stream (69 degrees horizontal field of view), the resolution
# of the paper's camera code for which outlier_min_neighbours = 20 was chosen.
REFERENCE_FOCAL_PX = 465.6
# The camera's distance to the robot (to the centre of its bounds) at which the counts were
# chosen and measured (docs/vision.md, "Other resolutions": the sample recordings, 536 mm;
# the studies' recordings are 536-548 mm away).
REFERENCE_DISTANCE_MM = 536.0


def settings_for_frame(settings: VisionSettings, focal_px: float, distance_mm: float
                       ) -> VisionSettings:
    """The settings a frame of a camera of focal length focal_px, seeing the robot from
    distance_mm, is processed with: settings_for_camera's while settings.scale_to_camera,
    else the counts as given; the decimation fixed either way."""
    if settings.scale_to_camera:
        return settings_for_camera(settings, focal_px, distance_mm)
    return replace(settings, decimation=_decimation(settings, focal_px, distance_mm))


def _decimation(settings: VisionSettings, focal_px: float, distance_mm: float) -> int:
    """settings.decimation, or decimation.decimation_factor when it is 0 (automatic)."""
    return settings.decimation or decimation_factor(focal_px, distance_mm, settings.voxel_mm)


def settings_for_camera(settings: VisionSettings, focal_px: float, distance_mm: float
                        ) -> VisionSettings:
    """The settings for a camera of focal length focal_px seeing the robot from distance_mm:
    the decimation fixed (settings.decimation, or decimation_factor when 0) and the neighbour
    counts scaled to the decimated image.

    outlier_min_neighbours and contact_min_neighbours are multiplied by the ratio of the
    robot's point density to that of the 640x480 D415 (REFERENCE_FOCAL_PX) at
    REFERENCE_DISTANCE_MM, where the counts were chosen, and rounded (at least 1 and 0): a
    camera further away sees fewer points (until 2026-12-01 the reference was the 640x480
    D415 at the same distance, and a 848x480 D415 at 753 mm filtered with 35 and 5 found
    none of 12 probe contacts; with 18 and 3, all). After the VoxelGrid a surface holds about one
    point per p max(p, v) of area, with p = distance_mm / f a pixel's footprint (f the focal
    length after decimation) and v the grid's leaf: p^2 while pixels are coarser than the
    leaf; finer ones are merged across the surface, but the depth noise spreads a leaf's
    pixels over leaves along the view. Measured on the sample probes' first frame at 536 mm
    (robot points' median neighbours within 5 mm, docs/vision.md): 17, 43 and 83 at 424x240,
    640x480 and 1280x720 (every pixel), ratios 0.40 and 1.93 where this gives 0.44 and 2.09.
    With the 640x480 counts at 424x240 the outlier filter removes most of the robot and no
    contact point has more than 3 robot neighbours; scaled with the focal length squared at
    1280x720 (80 and 12), 11 of 60 probe contacts went unseen. The result has
    scale_to_camera False.
    """
    factor = _decimation(settings, focal_px, distance_mm)

    def density(focal: float, distance: float) -> float:
        # a camera placed at the robot (a bad pose) still gets finite counts
        footprint = max(distance, 1e-9) / focal
        return 1.0 / (footprint * max(footprint, settings.voxel_mm))

    scale = (density(focal_px / factor, distance_mm)
             / density(REFERENCE_FOCAL_PX, REFERENCE_DISTANCE_MM))
    return replace(
        settings,
        decimation=factor,
        scale_to_camera=False,  # scaled once: process_frame must not scale these again
        outlier_min_neighbours=max(1, round(settings.outlier_min_neighbours * scale)),
        contact_min_neighbours=max(0, round(settings.contact_min_neighbours * scale)),
    )
