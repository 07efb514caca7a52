//! The simulator's frame renderer: what each simulated camera sees of the world snapshot.
//!
//! A procedural sample (height field + Lambert/Ward materials) on the turntable, lit by the
//! rig's halogen lamps, tube, backlight and line laser, seen through pinhole cameras and a
//! sensor model with shot and read noise. Each frame first makes an effect plan (see
//! [`effects`]) so that, for example, a flat sample never casts a shadow ray; the plan and its
//! reasons go into the frame notes.
//!
//! One concept per file: [`sample`] (procedural samples), [`heightfield`] (relief and ray
//! marching), [`shadow`] (per-vertex light visibility for preview), [`geometry`] (poses),
//! [`lights`], [`laser`], [`shading`] (the BRDF models), [`scene`] (intersection and direct
//! lighting), [`irradiance`] (direct light at texels), [`subsurface`] (dipole diffusion by
//! [`fft`] convolution), [`bounce`] (interreflection between relief texels) and
//! [`bounce_geometry`] (where its rays land, kept per sample), [`texgrid`], [`surface`],
//! `transport` (the passes a frame's plan turns on) and [`pass_cache`] (per-step sharing of
//! those passes), [`pixel_samples`]
//! (sub-pixel sampling and each camera's lens inversion, kept), [`primary_hits`] (each camera
//! view's first surfaces, kept while only the light changes), [`kept`] (their memory budget), [`effects`] (the plan), [`sensor`], [`quality`], [`rng`] (counter-based
//! noise), [`ground_truth`] (depth, normals, material, noise-free radiance per pixel) and
//! [`error`].
//!
//! Rows are rendered in parallel on the global rayon pool. Built samples and preview
//! visibility maps are cached in the [`Renderer`]; a camera that needs one being built by
//! another waits for it, so call `render` either from ordinary threads (as the simulated
//! cameras do) or from inside the rayon pool, not from both at once.

pub mod bounce;
pub mod bounce_geometry;
pub mod config;
pub mod dark_spans;
pub mod effects;
pub mod error;
pub mod fft;
pub mod geometry;
pub mod ground_truth;
pub mod heightfield;
pub mod irradiance;
pub mod kept;
pub mod kept_radiance;
pub mod laser;
pub mod lights;
pub mod material;
pub mod pass_cache;
pub mod pixel_samples;
pub mod primary_hits;
pub mod provenance;
pub mod quality;
pub mod rng;
pub mod sample;
pub mod scene;
pub mod sensor;
pub mod shading;
pub mod shadow;
pub mod subsurface;
pub mod surface;
pub mod texgrid;
mod transport;

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;
use serde_json::{Value, json};
use stagehand_devices::rig::{CameraSpec, LampKind, RigSpec};

pub use error::RenderError;

use crate::as_built::AsBuilt;
use crate::render::config::SimSpec;
use crate::world_snapshot::WorldSnapshot;
use geometry::{RigAngles, ToSample};
use laser::LaserSheet;
use quality::Knobs;
use sample::Sample;
use scene::{Scene, Shading};
use sensor::Sensor;

/// Largest sample edge accepted, in mm (the turntable is 400 mm across).
const MAX_SAMPLE_SIZE_MM: f64 = 1000.0;

/// The frame renderer for one rig. `Send + Sync`: cameras share it in an `Arc` and render
/// concurrently; built samples (per fixture) and preview shadow maps (per fixture and light
/// position) are cached inside.
#[derive(Debug)]
pub struct Renderer {
    rig: RigSpec,
    /// The rig's `[sim]` settings.
    sim: SimSpec,
    knobs: Knobs,
    samples: Mutex<HashMap<String, Arc<Sample>>>,
    visibility: shadow::VisibilityCache,
    passes: transport::TransportCaches,
    /// Each camera's undistorted sample points (the lens inversion), computed once.
    lens_tables: pixel_samples::LensTables,
    /// Each camera view's primary hits, kept while only the light changes.
    primary_hits: primary_hits::PrimaryHits,
    /// Each camera's latest radiance: an HDR bracket's exposures share one trace.
    radiance: kept_radiance::KeptRadiance,
    /// Runs of pixels laser frames skipped as black (see [`dark_spans`]), counted for tests
    /// and benchmarks.
    dark_spans_skipped: AtomicU64,
    /// The rig as built: nominal unless `[sim.as_built]` asks for deviations.
    as_built: AsBuilt,
}

/// Noise-free radiance seen by one camera, before the sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct RadianceImage {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Interleaved linear RGB radiance in reference units, row-major from the top-left.
    pub rgb: Vec<f32>,
    /// What was rendered and why (as [`Rendered::notes`], without the sensor).
    pub notes: Value,
}

/// One rendered frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Rendered {
    /// Interleaved RGB digital numbers (0..2^bit_depth − 1), width × height × 3, row-major
    /// from the top-left pixel.
    pub pixels: Vec<u16>,
    /// What was rendered and why: quality, fixture, the effect plan with reasons, lights,
    /// sensor settings and ray counts. Deterministic (no timings).
    pub notes: Value,
}

impl Renderer {
    /// A renderer for `rig`, at the rig's `sim.quality` preset.
    pub fn new(rig: &RigSpec) -> Result<Renderer, RenderError> {
        let knobs = SimSpec::of(rig)?.render_knobs()?;
        Renderer::with_knobs(rig, knobs)
    }

    /// A renderer for `rig` with explicit accuracy knobs (validated).
    pub fn with_knobs(rig: &RigSpec, knobs: Knobs) -> Result<Renderer, RenderError> {
        knobs.validate()?;
        let sim = SimSpec::of(rig)?;
        let size = sim.sample_size_mm;
        if !(size.is_finite() && size > 0.0 && size <= MAX_SAMPLE_SIZE_MM) {
            return Err(RenderError::InvalidSampleSize(size));
        }
        let as_built = sim
            .as_built
            .map_or_else(|| AsBuilt::nominal(rig), |spec| AsBuilt::draw(rig, spec));
        Ok(Renderer {
            rig: rig.clone(),
            as_built,
            sim,
            knobs,
            samples: Mutex::new(HashMap::new()),
            visibility: shadow::VisibilityCache::default(),
            passes: transport::TransportCaches::default(),
            lens_tables: pixel_samples::LensTables::default(),
            primary_hits: primary_hits::PrimaryHits::default(),
            radiance: kept_radiance::KeptRadiance::for_rig(rig),
            dark_spans_skipped: AtomicU64::new(0),
        })
    }

    /// The rig as built that this renderer draws (nominal without `[sim.as_built]`).
    pub fn as_built(&self) -> &AsBuilt {
        &self.as_built
    }

    /// The rig's `[sim]` settings this renderer was made with.
    pub fn sim(&self) -> &SimSpec {
        &self.sim
    }

    /// Black level (dark offset) in digital numbers that the sensor model adds for
    /// `camera_id`: 2% of its full scale. 0 for a camera the rig does not have.
    pub fn black_level_dn(&self, camera_id: &str) -> f64 {
        self.rig
            .camera(camera_id)
            .map_or(0.0, |c| sensor::black_level_dn(c.bit_depth))
    }

    /// The built sample for `fixture` (a built-in scene or a scene file path), from the cache
    /// or built now with the scene's `[render]` knobs resolved.
    fn sample(&self, fixture: &str) -> Result<Arc<Sample>, RenderError> {
        let mut cache = self
            .samples
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some(s) = cache.get(fixture) {
            return Ok(Arc::clone(s));
        }
        let scene = crate::scene_file::resolve_fixture(fixture)?
            .ok_or_else(|| RenderError::UnknownFixture(fixture.to_string()))?;
        // The scene's [render] settings decide the relief step, so resolve them first.
        let knobs = sample::scene_knobs(&scene, &self.knobs, &self.sim.knobs)?;
        let step_mm = knobs.as_ref().map_or(self.knobs.relief_mm, |k| k.relief_mm);
        let size_mm = self.sim.sample_size_mm as f32;
        let mut built = Sample::from_scene(fixture, scene, size_mm, step_mm);
        built.render_knobs = knobs;
        let built = Arc::new(built);
        cache.insert(fixture.to_string(), Arc::clone(&built));
        Ok(built)
    }

    /// Renders what camera `camera_id` sees of `world` for an exposure of `exposure_s`
    /// starting at `world.rig_time_s`, at `gain`, with sensor noise drawn from `noise_seed`.
    /// Exposure ≤ 0 yields black level plus read noise.
    pub fn render(
        &self,
        world: &WorldSnapshot,
        camera_id: &str,
        exposure_s: f64,
        gain: f64,
        noise_seed: u64,
    ) -> Result<Rendered, RenderError> {
        check_inputs(world, exposure_s, gain)?;
        let cam = self.camera(camera_id)?;
        // Light is integrated only for a positive exposure; dark frames skip tracing. The
        // exposures of a bracket see one world and share its trace.
        let integrate = exposure_s > 0.0;
        let radiance =
            self.radiance
                .get(camera_id, world, integrate, (cam.width, cam.height), || {
                    self.trace(world, cam, integrate)
                })?;
        let response = self.as_built.camera(&cam.id).sensor_response();
        let sensor =
            Sensor::new(cam.bit_depth, exposure_s, gain, noise_seed).with_response(response);
        let dark = sensor.dark_levels();
        let mut pixels = vec![0u16; radiance.rgb.len()];
        let width = cam.width as usize;
        pixels
            .par_chunks_mut(width * 3)
            .zip(radiance.rgb.par_chunks(width * 3))
            .enumerate()
            .for_each(|(y, (row, rad))| {
                let pixels = row.chunks_exact_mut(3).zip(rad.chunks_exact(3));
                for (x, (out, rgb)) in pixels.enumerate() {
                    let index = (y * width + x) as u64;
                    let rgb = [rgb[0], rgb[1], rgb[2]];
                    out.copy_from_slice(&sensor.digitise_rgb_with(&dark, rgb, index));
                }
            });
        let mut notes = radiance.notes.clone();
        notes["sensor"] = json!({
            "exposure_s": exposure_s,
            "gain": gain,
            "bit_depth": cam.bit_depth,
            "full_well_e": sensor::FULL_WELL_E,
            "read_noise_dn": sensor::READ_NOISE_DN_12BIT * gain * sensor::max_dn(cam.bit_depth) / 4095.0,
            "response": response.describe(),
            "light_integrated": notes["light_integrated"].clone(),
        });
        notes["black_level_dn"] = json!(sensor::black_level_dn(cam.bit_depth));
        if let Some(map) = notes.as_object_mut() {
            map.remove("light_integrated");
        }
        Ok(Rendered { pixels, notes })
    }

    /// Traces what camera `camera_id` will see of `world` before its frame is asked for (the
    /// rig settling: a lamp warming up, an axis moving), so that the frame, if it sees that
    /// world, reuses the trace (or waits for it) instead of tracing after its exposure.
    pub fn render_ahead(&self, world: &WorldSnapshot, camera_id: &str) -> Result<(), RenderError> {
        check_inputs(world, 1.0, 1.0)?;
        let cam = self.camera(camera_id)?;
        self.radiance
            .fill(camera_id, world, (cam.width, cam.height), || {
                self.trace(world, cam, true)
            })
    }

    /// Runs of [`primary_hits::SPAN`] pixels that laser frames have skipped as black since
    /// this renderer was made: how much of a sweep the kept hits spare.
    pub fn dark_spans_skipped(&self) -> u64 {
        self.dark_spans_skipped.load(Ordering::Relaxed)
    }

    /// Frames whose radiance was reused from an earlier frame of the same world (an HDR
    /// bracket's later exposures) since this renderer was made.
    pub fn radiance_reused(&self) -> u64 {
        self.radiance.reused()
    }

    /// The noise-free radiance camera `camera_id` sees of `world`, in reference units (white
    /// Lambert under the reference lamp = 1/π), before the sensor: the ground truth the
    /// tradeoff sweeps and error measures compare.
    pub fn radiance(
        &self,
        world: &WorldSnapshot,
        camera_id: &str,
    ) -> Result<RadianceImage, RenderError> {
        check_inputs(world, 1.0, 1.0)?;
        let cam = self.camera(camera_id)?;
        self.trace(world, cam, true)
    }

    /// The rig's camera `camera_id`, or an error listing the ones it has.
    fn camera(&self, camera_id: &str) -> Result<&CameraSpec, RenderError> {
        self.rig
            .camera(camera_id)
            .ok_or_else(|| RenderError::UnknownCamera {
                camera: camera_id.to_string(),
                rig: self.rig.rig.name.clone(),
                known: self
                    .rig
                    .cameras
                    .iter()
                    .map(|c| c.id.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// The knobs frames of `sample` are rendered with: its scene's `[render]` settings on top
    /// of the rig's, or the renderer's own when the scene has none.
    fn knobs_for<'s>(&'s self, sample: &'s Sample) -> &'s Knobs {
        sample.render_knobs.as_ref().unwrap_or(&self.knobs)
    }

    /// Traces every pixel of `cam` (or only sets up the notes when `integrate` is false).
    fn trace(
        &self,
        world: &WorldSnapshot,
        cam: &CameraSpec,
        integrate: bool,
    ) -> Result<RadianceImage, RenderError> {
        let sample = self.sample(&world.fixture)?;
        let knobs = self.knobs_for(&sample);
        let angles = RigAngles::from_world(&self.rig, &world.axes);
        let to_sample = ToSample::placed(angles.turntable_deg, &world.fixture_pose);
        let pose = self.as_built.camera(&cam.id).pose(cam, to_sample);
        let (lights, unknown_lamps) =
            lights::lit_lamps(&self.rig, &self.as_built, world, angles, to_sample);
        let laser = match &world.laser {
            None => None,
            Some(beam) => {
                let spec = self
                    .rig
                    .laser
                    .as_ref()
                    .ok_or_else(|| RenderError::NoLaser(self.rig.rig.name.clone()))?;
                let sheet = LaserSheet::built(
                    spec,
                    beam,
                    angles.light_arc_deg,
                    to_sample,
                    &self.as_built.laser(beam.mount_elevation_deg),
                );
                Some((sheet, beam.tilt_deg, beam.colour_nm, spec.power_mw))
            }
        };
        let relief = self.passes.relief.get(relief_key(&sample), || {
            bounce::relief_stats(sample.as_ref())
        });
        let probe = |shadows: bool| {
            let direct = irradiance::DirectLight {
                lights: &lights,
                laser: None,
                grid: sample.grid.as_ref(),
                shadows,
                tube_points: knobs.tube_samples,
            };
            let key = format!(
                "probe|{}|{lights:?}|{shadows}|{knobs:?}",
                relief_key(&sample)
            );
            let cells = sample.grid.as_ref().map_or(1, |g| g.cells());
            let texels = bounce::texels(cells, knobs.spp_side);
            *self.passes.probe.get(key, || {
                bounce::probe(sample.as_ref(), &direct, texels, knobs.bounce_rays)
            })
        };
        let plan = effects::plan(
            &sample,
            &lights,
            laser.as_ref().map(|l| (&l.0, l.1, l.2, l.3)),
            knobs,
            relief.as_ref().as_ref(),
            &probe,
        );
        let shading = Shading {
            shadows: plan.shadows.on,
            specular: plan.specular.on,
            knobs,
        };
        let tubes = lights::tube_bodies(&self.rig, world, to_sample);
        let tubes_key = format!("{tubes:?}");
        // Light is integrated only with something emitting; dark frames skip tracing and the
        // shadow maps.
        let lit = integrate && (!lights.is_empty() || laser.is_some());
        let visibility = |light| {
            let grid = sample.grid.as_ref().filter(|_| lit)?;
            Some(self.visibility.get(&sample.name, grid, light))
        };
        let transport = self.passes.run(
            &sample,
            &lights,
            laser.as_ref().map(|l| &l.0),
            &plan,
            knobs,
            lit,
        );
        let laser_on = laser.is_some();
        // Adaptive sampling: one sample per pixel first, the full count only where it differs.
        let adaptive = lit && knobs.adaptive_threshold > 0.0 && knobs.spp_side > 1;
        let lens = if lit && !adaptive {
            self.lens_tables.get(&pose, knobs.spp_side, laser_on)
        } else {
            None
        };
        let scene = Scene::new(
            &sample,
            lights,
            laser.map(|l| l.0),
            tubes,
            shading,
            &visibility,
        )
        .with_transport(
            transport.bounce.as_ref().and_then(|b| b.as_ref().as_ref()),
            transport
                .subsurface
                .as_ref()
                .and_then(|s| s.as_ref().as_ref()),
        );
        let (rgb, shadow_rays, refined) = if adaptive {
            let mut once = knobs.clone();
            once.spp_side = 1;
            let first = scene.with_knobs(&once);
            let lens1 = self.lens_tables.get(&pose, 1, laser_on);
            let hits1 = self.primary_hits(
                &first,
                &pose,
                lens1.as_deref(),
                hits_key(&sample, &pose, 1, &tubes_key),
                &once,
            );
            let (base, base_rays) = render_rows(
                &pose,
                |x, y, rays| {
                    first.pixel_with(&pose, lens1.as_deref(), hits1.as_deref(), None, x, y, rays)
                },
                |_, _| true,
            );
            let refine = contrast_mask(&base, cam.width, cam.height, knobs.adaptive_threshold);
            let (fine, fine_rays) = render_rows(
                &pose,
                |x, y, rays| scene.pixel_with(&pose, None, None, None, x, y, rays),
                |x, y| refine[y as usize * cam.width as usize + x as usize],
            );
            let rgb = base
                .chunks_exact(3)
                .zip(fine.chunks_exact(3))
                .zip(&refine)
                .flat_map(|((b, f), &r)| {
                    if r {
                        [f[0], f[1], f[2]]
                    } else {
                        [b[0], b[1], b[2]]
                    }
                })
                .collect();
            let count = refine.iter().filter(|&&r| r).count();
            (rgb, base_rays + fine_rays, Some(count))
        } else {
            let key = hits_key(&sample, &pose, knobs.spp_side, &tubes_key);
            let dims = (pose.width, pose.height, knobs.spp_side);
            // A frame lit by the laser alone builds its view's table before shading, to skip
            // what the sheet cannot reach; a lamp frame uses its view's kept table, or
            // records one as it shades.
            let laser_alone = scene.lit_by_laser_alone();
            let hits = match (lit, laser_alone) {
                (false, _) => None,
                (true, true) => {
                    self.primary_hits(&scene, &pose, lens.as_deref(), key.clone(), knobs)
                }
                (true, false) => self.primary_hits.kept(&key),
            };
            let record = match (lit && !laser_alone, &hits) {
                (true, None) => self.primary_hits.keeps(dims, true),
                _ => None,
            };
            let (rgb, rays) = if let Some(normals) = record {
                let mut table =
                    primary_hits::HitTable::empty(pose.width, pose.height, knobs.spp_side, normals);
                let traced = render_rows_recording(&pose, &mut table, |x, y, rays, row| {
                    scene.pixel_with(&pose, lens.as_deref(), None, Some(row), x, y, rays)
                });
                self.primary_hits.keep(key, table);
                traced
            } else {
                // A laser frame skips the runs of pixels the sheet cannot reach.
                let dark = hits.as_deref().and_then(|h| {
                    let spans = scene.dark_spans(&pose, h)?;
                    let skipped = spans.iter().filter(|&&d| d).count() as u64;
                    self.dark_spans_skipped
                        .fetch_add(skipped, Ordering::Relaxed);
                    Some((spans, h.spans_per_row()))
                });
                render_rows(
                    &pose,
                    |x, y, rays| {
                        scene.pixel_with(&pose, lens.as_deref(), hits.as_deref(), None, x, y, rays)
                    },
                    |x, y| {
                        lit && !dark
                            .as_ref()
                            .is_some_and(|(d, per_row)| dark_spans::in_dark_span(d, *per_row, x, y))
                    },
                )
            };
            (rgb, rays, None)
        };
        let notes = self.notes(&NoteInputs {
            knobs,
            camera: cam,
            sample: &sample,
            scene: &scene,
            plan: &plan,
            angles,
            world,
            unknown_lamps,
            shadow_rays,
            lit,
            transport: &transport,
            refined,
        });
        Ok(RadianceImage {
            width: cam.width,
            height: cam.height,
            rgb,
            notes,
        })
    }

    /// The primary hits of `pose`'s samples for the view `key` ([`hits_key`]), built now
    /// unless kept (with normals for a frame not lit by the laser alone, where they fit);
    /// `None` when too large to keep.
    fn primary_hits(
        &self,
        scene: &Scene<'_>,
        pose: &geometry::CameraPose,
        lens: Option<&pixel_samples::LensTable>,
        key: String,
        knobs: &Knobs,
    ) -> Option<Arc<primary_hits::HitTable>> {
        let side = knobs.spp_side;
        self.primary_hits.get(
            key,
            (pose.width, pose.height, side),
            !scene.lit_by_laser_alone(),
            |normals| {
                primary_hits::HitTable::build(
                    pose.width,
                    pose.height,
                    side,
                    pose.origin,
                    normals,
                    |x, y, sub| scene.locate_sample(pose, lens, x, y, sub),
                )
            },
        )
    }

    fn notes(&self, n: &NoteInputs<'_>) -> Value {
        let lights: Vec<Value> = n
            .scene
            .lights()
            .iter()
            .map(|l| {
                let kind = match l.kind {
                    LampKind::Halogen => "halogen",
                    LampKind::Tube => "tube",
                    LampKind::Backlight => "backlight",
                };
                json!({ "id": l.id, "kind": kind, "output": l.output })
            })
            .collect();
        let mut notes = json!({
            "renderer": "stagehand-sim direct lighting v1",
            "camera": n.camera.id,
            "fixture": n.sample.name,
            "quality": n.knobs.preset,
            "knobs": serde_json::to_value(n.knobs).unwrap_or(Value::Null),
            "effects": n.plan.to_json(),
            "lights": lights,
            "geometry": {
                "turntable_deg": n.angles.turntable_deg,
                "light_arc_deg": n.angles.light_arc_deg,
                "cart_mm": n.world.cart_mm,
                "sample_size_mm": n.sample.size_mm,
                "relief_max_mm": n.sample.grid.as_ref().map_or(0.0, |g| g.zmax()),
                "relief_grid_mm": n.sample.grid.as_ref().map(|g| n.sample.size_mm / g.cells() as f32),
            },
            "light_integrated": n.lit,
            "stats": { "shadow_rays": n.shadow_rays, "visibility_maps": n.scene.visibility_maps() },
        });
        if let (Some(stats), Some(extra)) = (
            notes["stats"].as_object_mut(),
            n.transport.stats().as_object().cloned(),
        ) {
            stats.extend(extra);
        }
        if n.plan.shadows.on {
            notes["effects"]["shadows"]["method"] = json!(if n.scene.visibility_maps() > 0 {
                "preview: per-vertex visibility maps toward each light position (tube: 4 \
                 positions), bilinear over the relief grid; rays elsewhere"
            } else {
                "one shadow ray per light sample"
            });
        }
        if let Some(refined) = n.refined {
            notes["stats"]["adaptive_refined_pixels"] = json!(refined);
        }
        if !n.unknown_lamps.is_empty() {
            notes["ignored_lamps"] = json!(n.unknown_lamps);
        }
        notes
    }
}

/// Everything the notes record about one frame.
struct NoteInputs<'a> {
    knobs: &'a Knobs,
    camera: &'a CameraSpec,
    sample: &'a Sample,
    scene: &'a Scene<'a>,
    plan: &'a effects::Plan,
    angles: RigAngles,
    world: &'a WorldSnapshot,
    unknown_lamps: Vec<String>,
    shadow_rays: u64,
    lit: bool,
    transport: &'a transport::Transport,
    /// Pixels adaptive sampling rendered at the full sample count (`None` when off).
    refined: Option<usize>,
}

/// [`render_rows`] for a frame that shades every pixel, recording its view's primary hits
/// into `table` row by row as it goes (`pixel` gets the row's recorder).
fn render_rows_recording(
    pose: &geometry::CameraPose,
    table: &mut primary_hits::HitTable,
    pixel: impl Fn(u32, u32, &mut u64, &mut primary_hits::RowRecorder<'_>) -> glam::Vec3A + Sync,
) -> (Vec<f32>, u64) {
    let width = pose.width as usize;
    let mut rgb = vec![0f32; width * pose.height as usize * 3];
    let rays = rgb
        .par_chunks_mut(width * 3)
        .zip(table.rows(pose.origin))
        .enumerate()
        .map(|(y, (row, mut record))| {
            let mut rays = 0u64;
            for (x, out) in row.chunks_exact_mut(3).enumerate() {
                let radiance = pixel(x as u32, y as u32, &mut rays, &mut record);
                out.copy_from_slice(&radiance.to_array());
            }
            rays
        })
        .sum();
    (rgb, rays)
}

/// Renders the pixels of `pose` where `want(x, y)` with `pixel` (rows in parallel; the others
/// stay black): the RGB image and the shadow rays marched.
fn render_rows(
    pose: &geometry::CameraPose,
    pixel: impl Fn(u32, u32, &mut u64) -> glam::Vec3A + Sync,
    want: impl Fn(u32, u32) -> bool + Sync,
) -> (Vec<f32>, u64) {
    let width = pose.width as usize;
    let mut rgb = vec![0f32; width * pose.height as usize * 3];
    let rays = rgb
        .par_chunks_mut(width * 3)
        .enumerate()
        .map(|(y, row)| {
            let mut rays = 0u64;
            for x in 0..width {
                if want(x as u32, y as u32) {
                    let radiance = pixel(x as u32, y as u32, &mut rays);
                    row[x * 3..x * 3 + 3].copy_from_slice(&radiance.to_array());
                }
            }
            rays
        })
        .sum();
    (rgb, rays)
}

/// Adaptive sampling's choice: the pixels of `rgb` (one sample each) that differ in some
/// channel from a 4-neighbour by more than `threshold` × the image's mean value.
fn contrast_mask(rgb: &[f32], width: u32, height: u32, threshold: f32) -> Vec<bool> {
    let (w, h) = (width as usize, height as usize);
    let mean = rgb.iter().map(|&v| v as f64).sum::<f64>() / rgb.len().max(1) as f64;
    let limit = threshold * mean as f32;
    let differs =
        |a: usize, b: usize| (0..3).any(|c| (rgb[a * 3 + c] - rgb[b * 3 + c]).abs() > limit);
    let mut mask = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if x + 1 < w && differs(i, i + 1) {
                mask[i] = true;
                mask[i + 1] = true;
            }
            if y + 1 < h && differs(i, i + w) {
                mask[i] = true;
                mask[i + w] = true;
            }
        }
    }
    mask
}

/// The key of the primary hits of `pose`'s samples: every input of the intersection exactly,
/// the sample and its relief, the pose (the turntable angle and fixture pose are in it), the
/// samples per pixel side and the tube's body (`tubes`).
fn hits_key(sample: &Sample, pose: &geometry::CameraPose, side: u32, tubes: &str) -> String {
    format!("{}|{pose:?}|{side}|{tubes}", relief_key(sample))
}

/// Cache key of a sample's relief statistics.
fn relief_key(sample: &Sample) -> String {
    format!(
        "{}|{}",
        sample.name,
        sample.grid.as_ref().map_or(0, |g| g.cells())
    )
}

/// Rejects numbers that would make the frame meaningless (NaN angles, negative gain, ...).
fn check_inputs(world: &WorldSnapshot, exposure_s: f64, gain: f64) -> Result<(), RenderError> {
    let bad = |what: String, expected: &'static str, got: f64| {
        Err(RenderError::InvalidInput {
            what,
            expected,
            got,
        })
    };
    if !exposure_s.is_finite() {
        return bad(
            "exposure_s".into(),
            "a finite number of seconds",
            exposure_s,
        );
    }
    if !(gain.is_finite() && gain > 0.0) {
        return bad("gain".into(), "a positive finite factor", gain);
    }
    for (id, &deg) in &world.axes {
        if !deg.is_finite() {
            return bad(format!("axis `{id}` angle"), "finite degrees", deg);
        }
    }
    for (id, &out) in &world.lamps {
        if !(out.is_finite() && out >= 0.0) {
            return bad(
                format!("lamp `{id}` output"),
                "a fraction of steady state ≥ 0",
                out,
            );
        }
    }
    if !world.cart_mm.is_finite() {
        return bad("cart_mm".into(), "finite millimetres", world.cart_mm);
    }
    if let Some(beam) = &world.laser {
        for (what, v) in [
            ("laser tilt_deg", beam.tilt_deg),
            ("laser mount_elevation_deg", beam.mount_elevation_deg),
        ] {
            if !v.is_finite() {
                return bad(what.into(), "finite degrees", v);
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod reuse_tests;
#[cfg(test)]
mod tests;
