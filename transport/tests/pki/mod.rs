//! The test PKI of the Zenoh security tests (`transport/tests/zenoh_security.rs`) and the
//! secure-link process test (`tests/processes.rs`): a test CA, leaf certificates for the slave,
//! the master and a monitor, and a rogue CA with a rogue "h4-master", generated with `rcgen`.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)]

use std::fs;
use std::path::Path;

use rcgen::{
    BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair,
    KeyUsagePurpose,
};

pub fn new_ca(name: &str) -> (String, Issuer<'static, KeyPair>) {
    let mut params = CertificateParams::new(Vec::<String>::new()).unwrap();
    params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    params.distinguished_name.push(DnType::CommonName, name);
    params.key_usages = vec![
        KeyUsagePurpose::DigitalSignature,
        KeyUsagePurpose::KeyCertSign,
        KeyUsagePurpose::CrlSign,
    ];
    let key = KeyPair::generate().unwrap();
    let cert = params.self_signed(&key).unwrap();
    (cert.pem(), Issuer::new(params, key))
}

/// Writes `<file>.pem` and `<file>-key.pem`: a certificate for common name `cn` (usable as
/// TLS server and client) signed by `issuer`.
pub fn leaf(dir: &Path, file: &str, cn: &str, issuer: &Issuer<'static, KeyPair>) {
    let mut params =
        CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()]).unwrap();
    params.distinguished_name.push(DnType::CommonName, cn);
    params.use_authority_key_identifier_extension = true;
    params.key_usages = vec![
        KeyUsagePurpose::DigitalSignature,
        KeyUsagePurpose::KeyEncipherment,
    ];
    params.extended_key_usages = vec![
        ExtendedKeyUsagePurpose::ServerAuth,
        ExtendedKeyUsagePurpose::ClientAuth,
    ];
    let key = KeyPair::generate().unwrap();
    let cert = params.signed_by(&key, issuer).unwrap();
    fs::write(dir.join(format!("{file}.pem")), cert.pem()).unwrap();
    fs::write(dir.join(format!("{file}-key.pem")), key.serialize_pem()).unwrap();
}

/// The test PKI: `ca.pem`; `slave`, `master`, `monitor` signed by it; `rogue-master` (common
/// name "h4-master") signed by another CA.
pub fn write_pki(dir: &Path) {
    let (ca_pem, ca) = new_ca("h4-test-ca");
    fs::write(dir.join("ca.pem"), ca_pem).unwrap();
    leaf(dir, "slave", "h4-slave", &ca);
    leaf(dir, "master", "h4-master", &ca);
    leaf(dir, "monitor", "h4-monitor", &ca);
    let (rogue_ca_pem, rogue_ca) = new_ca("rogue-ca");
    fs::write(dir.join("rogue-ca.pem"), rogue_ca_pem).unwrap();
    leaf(dir, "rogue-master", "h4-master", &rogue_ca);
}
