//! The renderer's per-point surface description: which reflectance model, its parameters,
//! transmittance for the backlight, and the subsurface medium (dipole) beneath the surface.
//! The models themselves live in [`crate::materials`]; this is the compact f32 record the
//! renderer stores per texel and shades with.

use glam::Vec3A;

/// Which BRDF a surface point reflects with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Model {
    /// ρd/π only.
    #[default]
    Lambert,
    /// ρd/π + ρs·isotropic Ward(α).
    WardIso,
    /// ρd/π + ρs·anisotropic Ward(αx along the tangent, αy across it).
    WardAniso,
    /// ρd/π + ρs·normalised Blinn–Phong with exponent 2/α² − 2.
    BlinnPhong,
    /// ρd/π + Cook–Torrance with GGX distribution, height-correlated Smith masking and
    /// Schlick Fresnel with F0 = ks.
    Ggx,
}

impl Model {
    /// The name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            Model::Lambert => "lambert",
            Model::WardIso => "ward",
            Model::WardAniso => "ward_aniso",
            Model::BlinnPhong => "blinn_phong",
            Model::Ggx => "ggx",
        }
    }

    /// Parses a scene file's model name.
    pub fn parse(name: &str) -> Option<Model> {
        Some(match name {
            "lambert" => Model::Lambert,
            "ward" | "ward_iso" => Model::WardIso,
            "ward_aniso" => Model::WardAniso,
            "blinn_phong" => Model::BlinnPhong,
            "ggx" | "cook_torrance" => Model::Ggx,
            _ => return None,
        })
    }
}

/// A homogeneous scattering medium under the surface, for the dipole BSSRDF (Jensen et al.
/// 2001; see [`crate::materials::dipole`]). Coefficients per RGB channel in 1/mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Medium {
    /// Absorption coefficient σa.
    pub sigma_a: Vec3A,
    /// Reduced scattering coefficient σ′s.
    pub sigma_s_prime: Vec3A,
    /// Relative index of refraction η.
    pub eta: f32,
}

/// Reflectance at a surface point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// The specular model (the diffuse term is always Lambert ρd/π).
    pub model: Model,
    /// Diffuse albedo ρd per channel, linear. Zero under a subsurface medium, whose dipole
    /// supplies the diffuse light instead.
    pub albedo: Vec3A,
    /// Specular albedo ρs (Ward, Blinn–Phong) or normal-incidence reflectance F0 (GGX).
    pub ks: f32,
    /// Roughness: Ward α (αx when anisotropic), GGX α; Blinn–Phong exponent 2/α² − 2.
    pub alpha: f32,
    /// Anisotropic Ward roughness across the tangent (αy).
    pub alpha_y: f32,
    /// Direction of the anisotropic tangent in the sample's xy plane, radians from +x.
    pub tangent_rad: f32,
    /// Fraction of the backlight that reaches the camera through the sample, per channel.
    pub transmittance: Vec3A,
    /// Index+1 into the sample's media of the medium under this point; 0 for opaque.
    pub medium: u8,
    /// Quasi-homogeneous mesostructure: the entrance function, the fraction of incident light
    /// that enters the medium here (1 = homogeneous).
    pub meso_in: f32,
    /// Quasi-homogeneous mesostructure: the exit function, the fraction of subsurface light
    /// that leaves the medium here (1 = homogeneous).
    pub meso_out: f32,
}

impl Material {
    /// An opaque grey Lambertian surface.
    pub const fn grey(albedo: f32) -> Material {
        Material::lambert(Vec3A::splat(albedo))
    }

    /// An opaque Lambertian surface.
    pub const fn lambert(albedo: Vec3A) -> Material {
        Material {
            model: Model::Lambert,
            albedo,
            ks: 0.0,
            alpha: 0.2,
            alpha_y: 0.2,
            tangent_rad: 0.0,
            transmittance: Vec3A::ZERO,
            medium: 0,
            meso_in: 1.0,
            meso_out: 1.0,
        }
    }

    /// Lambert plus an isotropic Ward lobe (the thesis' SVBRDF model).
    pub const fn ward(albedo: Vec3A, ks: f32, alpha: f32) -> Material {
        Material {
            model: Model::WardIso,
            ks,
            alpha,
            alpha_y: alpha,
            ..Material::lambert(albedo)
        }
    }

    /// Whether this point has a specular term at all.
    pub fn has_specular(&self) -> bool {
        self.model != Model::Lambert && self.ks > 0.0
    }
}
