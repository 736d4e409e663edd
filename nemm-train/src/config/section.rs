//! The one definition of a configuration section ([`section!`]): each field written once,
//! with its doc, its type, its default, its TOML attributes and its command-line option.

/// How a command-line option of type `Self` overrides a configuration field of type `T`.
pub(super) trait Overlay<T> {
    /// Sets `field` when the option is given.
    fn overlay(&self, field: &mut T);
}

/// An option given replaces the field.
impl<T: Clone> Overlay<T> for Option<T> {
    fn overlay(&self, field: &mut T) {
        if let Some(v) = self {
            *field = v.clone();
        }
    }
}

/// An optional field (`None`: decided later or unbounded): an option given replaces it.
impl<T: Clone> Overlay<Option<T>> for Option<T> {
    fn overlay(&self, field: &mut Option<T>) {
        if self.is_some() {
            field.clone_from(self);
        }
    }
}

/// A list given for one number sets it only when it holds one value (`--lambda-ph`, which
/// `nemm sweep` reads as the list of its jobs).
impl Overlay<f64> for Option<Vec<f64>> {
    fn overlay(&self, field: &mut f64) {
        if let Some([one]) = self.as_deref() {
            *field = *one;
        }
    }
}

/// Defines one section of a job's configuration from a single list of fields: the resolved
/// struct (serde, `#[serde(default, deny_unknown_fields)]`: a table of a `--config` file and
/// of the saved `config.toml`), its `Default` (the field defaults), the command-line struct
/// (`clap::Args`, every field an `Option` that is `None` when not given) and its `over`,
/// which applies the options given onto a resolved section.
///
/// Each field is written as
///
/// ```text
/// /// Doc of the field (both structs).
/// #[serde(...)]            // optional: on the resolved field
/// #[arg(...)]              // the option (`#[arg(skip)]`: config file only)
/// name: Type = default, OptionType;
/// ```
///
/// where `OptionType` overlays `Type` ([`Overlay`]): `Option<Type>`, or `Option<T>` for an
/// `Option<T>` field.
macro_rules! section {
    (
        $(#[$config_attr:meta])*
        pub struct $config:ident;
        $(#[$options_attr:meta])*
        pub struct $options:ident;
        $(
            $(#[doc = $doc:literal])*
            $(#[serde($($serde:tt)*)])*
            #[arg($($arg:tt)*)]
            $name:ident: $ty:ty = $default:expr, $given:ty;
        )*
    ) => {
        $(#[$config_attr])*
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(default, deny_unknown_fields)]
        pub struct $config {
            $(
                $(#[doc = $doc])*
                $(#[serde($($serde)*)])*
                pub $name: $ty,
            )*
        }

        impl Default for $config {
            fn default() -> Self {
                Self {
                    $($name: $default,)*
                }
            }
        }

        $(#[$options_attr])*
        #[derive(Debug, Clone, Default, PartialEq, clap::Args)]
        pub struct $options {
            $(
                $(#[doc = $doc])*
                #[arg($($arg)*)]
                pub $name: $given,
            )*
        }

        impl $options {
            /// Applies the options given onto `c` (the defaults, or a `--config` file).
            pub fn over(&self, c: &mut $config) {
                $($crate::config::section::Overlay::overlay(&self.$name, &mut c.$name);)*
            }
        }
    };
}

pub(super) use section;
