//! Opening a process's end of the link from its command-line options: `--transport`,
//! `--arm-id`, the iceoryx2 prefix and the Zenoh endpoints, shared by `h4-slave run`,
//! `h4-master run` and `h4-master loopback` (flattened into their clap arguments).

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use h4_shared::wire::{Command, Feedback, WireMessage};

use crate::Link;
use crate::iceoryx2::{self as iox, Iceoryx2Error, Iceoryx2Options};
use crate::zenoh::{ZenohConfig, ZenohError, ZenohLink, ZenohMode};

/// Why a link end could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// iceoryx2 refused the node, the services or the ports.
    #[error(transparent)]
    Iceoryx2(#[from] Iceoryx2Error),
    /// Zenoh refused the configuration or the session.
    #[error(transparent)]
    Zenoh(#[from] ZenohError),
}

/// The transport between the two processes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TransportKind {
    /// iceoryx2 shared memory (same host).
    Iceoryx2,
    /// Eclipse Zenoh (same host or between hosts).
    Zenoh,
}

/// Transport options.
#[derive(Clone, Debug, Args)]
pub struct TransportArgs {
    /// Transport to the other side.
    #[arg(long, value_enum, default_value_t = TransportKind::Iceoryx2)]
    pub transport: TransportKind,
    /// Arm id: selects the iceoryx2 services / Zenoh key expressions `h4/<arm-id>/…`.
    #[arg(long, default_value_t = 0)]
    pub arm_id: u16,
    /// iceoryx2 service name prefix.
    #[arg(long, default_value = "h4")]
    pub iceoryx2_prefix: String,
    /// Zenoh mode: peer or client.
    #[arg(long, value_parser = ["peer", "client"], default_value = "peer")]
    pub zenoh_mode: String,
    /// Zenoh endpoint to listen on (repeatable), e.g. tcp/127.0.0.1:7447. Loopback only
    /// unless you name another address.
    #[arg(long = "zenoh-listen", value_name = "ENDPOINT")]
    pub zenoh_listen: Vec<String>,
    /// Zenoh endpoint to connect to (repeatable), e.g. tcp/127.0.0.1:7447.
    #[arg(long = "zenoh-connect", value_name = "ENDPOINT")]
    pub zenoh_connect: Vec<String>,
    /// Zenoh json5 configuration file (TLS, user/password, access control); the options
    /// above are applied over it.
    #[arg(long = "zenoh-config", value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

impl TransportArgs {
    /// iceoryx2 on `arm_id` under `iceoryx2_prefix`, Zenoh options at their defaults.
    pub fn iceoryx2(arm_id: u16, iceoryx2_prefix: String) -> Self {
        TransportArgs {
            transport: TransportKind::Iceoryx2,
            arm_id,
            iceoryx2_prefix,
            zenoh_mode: "peer".into(),
            zenoh_listen: vec![],
            zenoh_connect: vec![],
            zenoh_config: None,
        }
    }

    /// The arguments that reproduce these options on another command line.
    pub fn to_args(&self) -> Vec<String> {
        let mut v = vec![
            "--transport".to_string(),
            match self.transport {
                TransportKind::Iceoryx2 => "iceoryx2",
                TransportKind::Zenoh => "zenoh",
            }
            .to_string(),
            "--arm-id".to_string(),
            self.arm_id.to_string(),
            "--iceoryx2-prefix".to_string(),
            self.iceoryx2_prefix.clone(),
            "--zenoh-mode".to_string(),
            self.zenoh_mode.clone(),
        ];
        for e in &self.zenoh_listen {
            v.extend(["--zenoh-listen".to_string(), e.clone()]);
        }
        for e in &self.zenoh_connect {
            v.extend(["--zenoh-connect".to_string(), e.clone()]);
        }
        if let Some(f) = &self.zenoh_config {
            v.extend(["--zenoh-config".to_string(), f.display().to_string()]);
        }
        v
    }

    fn zenoh(&self) -> ZenohConfig {
        ZenohConfig {
            mode: if self.zenoh_mode == "client" {
                ZenohMode::Client
            } else {
                ZenohMode::Peer
            },
            listen: self.zenoh_listen.clone(),
            connect: self.zenoh_connect.clone(),
            config_file: self.zenoh_config.as_ref().map(|p| p.display().to_string()),
            ..ZenohConfig::default()
        }
    }

    fn iceoryx2_options(&self) -> Iceoryx2Options {
        match iox::remove_stale_nodes() {
            Ok(0) => {}
            Ok(n) => eprintln!("iceoryx2: removed the resources of {n} dead process(es)"),
            Err(e) => eprintln!("warning: {e}"),
        }
        Iceoryx2Options {
            prefix: self.iceoryx2_prefix.clone(),
            ..Iceoryx2Options::new(self.arm_id)
        }
    }

    /// Opens a Zenoh end and claims `role` on its arm ([`ZenohLink::claim_role`]): a second
    /// master or slave on the same key expressions is refused.
    fn open_zenoh<Out: WireMessage, In: WireMessage>(
        &self,
        role: &str,
    ) -> Result<Box<dyn Link<Out, In>>, OpenError> {
        let mut link = ZenohLink::<Out, In>::open(self.arm_id, &self.zenoh())?;
        link.claim_role(role, ROLE_QUERY_TIMEOUT)?;
        Ok(Box::new(link))
    }

    /// Opens the slave's end (publishes feedback, receives commands). For iceoryx2, the
    /// resources of dead processes are removed first (reported on stderr). A second slave on
    /// the same arm (and iceoryx2 prefix) is refused: iceoryx2 allows one publisher per
    /// service, Zenoh checks the slave's liveliness token.
    pub fn open_slave(&self) -> Result<Box<dyn Link<Feedback, Command>>, OpenError> {
        match self.transport {
            TransportKind::Iceoryx2 => Ok(Box::new(iox::slave(&self.iceoryx2_options())?)),
            TransportKind::Zenoh => self.open_zenoh("slave"),
        }
    }

    /// Opens the master's end (publishes commands, receives feedback). For iceoryx2, the
    /// resources of dead processes are removed first (reported on stderr). A second master
    /// is refused as a second slave is.
    pub fn open_master(&self) -> Result<Box<dyn Link<Command, Feedback>>, OpenError> {
        match self.transport {
            TransportKind::Iceoryx2 => Ok(Box::new(iox::master(&self.iceoryx2_options())?)),
            TransportKind::Zenoh => self.open_zenoh("master"),
        }
    }
}

/// How long a process opening a Zenoh end waits for the answers to its liveliness query
/// (is another master / slave of this arm alive?).
pub const ROLE_QUERY_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(1);
