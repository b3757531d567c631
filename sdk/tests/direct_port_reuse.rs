//! Direct mode (`central -c`): a module that connects after another left
//! takes the listen port the other had (C's modules take the first free
//! port from 8000, and so do Courier's). A module that had a link to the
//! one that left must link anew to the newcomer: it kept writing to the
//! dead link, so its publishes and queries to the newcomer were lost
//! (publish said `Ok`, the query timed out).

use std::time::Duration;

use courier::central::{CentralServer, Config};
use courier::Session;
use futures::StreamExt;

const T: Duration = Duration::from_secs(20);

async fn session(url: &str, name: &str) -> Session {
    let s = Session::builder(url).name(name).connect();
    tokio::time::timeout(T, s).await.unwrap().unwrap()
}

#[tokio::test]
async fn a_module_on_the_port_of_one_that_left_gets_its_messages() {
    let mut config = Config::default();
    config.direct = true;
    let central = CentralServer::builder()
        .port(0)
        .config(config)
        .spawn()
        .await
        .unwrap();
    let url = format!("ipc://{}", central.local_addr());
    let a = session(&url, "a").await;
    let c = session(&url, "c").await;
    let mut sub = c.subscribe::<u32>("ctr").await.unwrap();
    a.publish("ctr", &1u32).await.unwrap();
    let got = tokio::time::timeout(T, sub.next()).await.unwrap();
    assert_eq!(got.unwrap().unwrap().value, 1);
    // c leaves; srv comes, most likely on c's port
    c.close().await;
    let srv = session(&url, "srv").await;
    let mut reqs = srv.serve::<u32, u32>("double", "").await.unwrap();
    let server = tokio::spawn(async move {
        while let Some(Ok(r)) = reqs.next().await {
            let v = r.value;
            let _ = r.reply(&(v * 2)).await;
        }
    });
    let r = a.query::<u32, u32>("double", &21).timeout(T).await;
    assert_eq!(r.unwrap(), 42, "a query of a to the newcomer");
    let mut bcast = srv.subscribe::<u32>("bcast").await.unwrap();
    a.publish("bcast", &3u32).await.unwrap();
    let got = tokio::time::timeout(T, bcast.next()).await;
    assert_eq!(
        got.expect("a's broadcast reaches the newcomer")
            .unwrap()
            .unwrap()
            .value,
        3
    );
    server.abort();
    a.close().await;
    srv.close().await;
    central.shutdown().await;
}
