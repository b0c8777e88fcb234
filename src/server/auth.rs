//! Bearer tokens on the routes that take a posted scene (`--require-token`): only an
//! instructor may render, trace, validate or grade an arbitrary scene, since whoever can
//! render a scene holds its answer key. Without the setting these routes stay open and
//! this layer is not installed at all.
//!
//! A missing, malformed, unknown or revoked token is 401 with `WWW-Authenticate: Bearer`;
//! a grader's token is 403. Tokens are never logged: the log names the token's id.

use axum::extract::{Request, State};
use axum::http::{HeaderMap, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::AppState;
use super::error::ApiError;
use crate::store::tokens::{hash_token, hashes_equal};
use crate::store::{Principal, Role, Secret, Store};

/// The id a request authenticated by `RAYTILE_ADMIN_TOKEN` is logged under.
pub const ADMIN_ID: &str = "admin";

/// What tokens are checked against: the store, and the bootstrap admin token's hash.
#[derive(Debug, Clone)]
pub struct Auth {
    store: Store,
    admin: Option<[u8; 32]>,
}

impl Auth {
    /// Checks tokens against `store`, and accepts `admin` (hashed now, the token itself
    /// dropped) as an instructor.
    pub fn new(store: Store, admin: Option<&Secret>) -> Auth {
        Auth {
            store,
            admin: admin
                .map(|s| s.expose().trim())
                .filter(|s| !s.is_empty())
                .map(hash_token),
        }
    }

    /// The store the tokens live in.
    pub fn store(&self) -> &Store {
        &self.store
    }

    /// Who the request's `Authorization: Bearer` token speaks for; 401 without a valid one.
    pub async fn principal(&self, headers: &HeaderMap) -> Result<Principal, ApiError> {
        let token = bearer(headers)?;
        if let Some(admin) = &self.admin
            && hashes_equal(admin, &hash_token(token))
        {
            return Ok(Principal {
                id: ADMIN_ID.into(),
                role: Role::Instructor,
                assignment: None,
            });
        }
        match self.store.authenticate(token).await {
            Ok(Some(p)) => Ok(p),
            Ok(None) => Err(ApiError::Unauthorized(
                "the bearer token is unknown or revoked".into(),
            )),
            Err(e) => Err(ApiError::Internal(format!("cannot check the token: {e}"))),
        }
    }

    /// An instructor's principal; 401 without a valid token, 403 for another role.
    pub async fn instructor(&self, headers: &HeaderMap) -> Result<Principal, ApiError> {
        let p = self.principal(headers).await?;
        match p.role {
            Role::Instructor => Ok(p),
            Role::Grader => Err(ApiError::Forbidden(
                "this route needs an instructor's token; a grader's token may only fetch \
                 and submit its assignment"
                    .into(),
            )),
        }
    }
}

/// Lets `p` at assignment `id`'s scenes and submissions: an instructor, or a grader
/// scoped to it (or to every assignment); 403 for a grader of another assignment.
pub fn scoped_to(p: &Principal, id: &str) -> Result<(), ApiError> {
    match (p.role, p.assignment.as_deref()) {
        (Role::Instructor, _) | (Role::Grader, None) => Ok(()),
        (Role::Grader, Some(a)) if a == id => Ok(()),
        (Role::Grader, Some(_)) => Err(ApiError::Forbidden(
            "this grader's token is scoped to another assignment".into(),
        )),
    }
}

/// Whether `p` sees assignment `id` in a listing (as [`scoped_to`] lets it at it).
pub fn sees(p: &Principal, id: &str) -> bool {
    scoped_to(p, id).is_ok()
}

/// The token of `Authorization: Bearer <token>` (the scheme in any case, RFC 9110).
fn bearer(headers: &HeaderMap) -> Result<&str, ApiError> {
    let missing = || {
        ApiError::Unauthorized(
            "this server requires a bearer token: send `Authorization: Bearer <token>`".into(),
        )
    };
    let value = headers
        .get(header::AUTHORIZATION)
        .ok_or_else(missing)?
        .to_str()
        .map_err(|_| missing())?;
    let (scheme, token) = value.trim().split_once(' ').ok_or_else(missing)?;
    let token = token.trim();
    if !scheme.eq_ignore_ascii_case("bearer") || token.is_empty() {
        return Err(missing());
    }
    Ok(token)
}

/// The middleware of the scene routes under `--require-token`: lets instructors through.
pub async fn require_instructor(
    State(state): State<AppState>,
    req: Request,
    next: Next,
) -> Response {
    let Some(auth) = &state.auth else {
        // Installed only with an `Auth`; without one nobody can be let in.
        return ApiError::Internal("--require-token without a token store".into()).into_response();
    };
    match auth.instructor(req.headers()).await {
        Ok(p) => {
            tracing::debug!(token_id = %p.id, "authenticated");
            next.run(req).await
        }
        Err(e) => e.into_response(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    fn with_auth(v: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::AUTHORIZATION, HeaderValue::from_str(v).unwrap());
        h
    }

    #[test]
    fn the_bearer_scheme_is_read_in_any_case_and_nothing_else() {
        assert_eq!(bearer(&with_auth("Bearer rt_abc")).unwrap(), "rt_abc");
        assert_eq!(bearer(&with_auth("bearer  rt_abc ")).unwrap(), "rt_abc");
        for bad in ["Basic dXNlcjpwYXNz", "Bearer", "Bearer ", "rt_abc"] {
            assert!(
                matches!(bearer(&with_auth(bad)), Err(ApiError::Unauthorized(_))),
                "{bad}"
            );
        }
        assert!(matches!(
            bearer(&HeaderMap::new()),
            Err(ApiError::Unauthorized(_))
        ));
    }

    #[tokio::test]
    async fn roles_decide_and_the_admin_token_is_an_instructor() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open_dir(dir.path()).await.unwrap();
        let grader = store.create_token(Role::Grader, Some("a1")).await.unwrap();
        let teacher = store.create_token(Role::Instructor, None).await.unwrap();
        let auth = Auth::new(store, Some(&Secret::new("boot-strap")));
        let bearer_of = |t: &str| with_auth(&format!("Bearer {t}"));

        let p = auth
            .instructor(&bearer_of(teacher.token.expose()))
            .await
            .unwrap();
        assert_eq!(p.id, teacher.id);
        let admin = auth.instructor(&bearer_of("boot-strap")).await.unwrap();
        assert_eq!(admin.id, ADMIN_ID);
        assert!(matches!(
            auth.instructor(&bearer_of(grader.token.expose())).await,
            Err(ApiError::Forbidden(_))
        ));
        assert!(matches!(
            auth.instructor(&bearer_of("boot-strap-not")).await,
            Err(ApiError::Unauthorized(_))
        ));
        // Without an admin token configured, none is accepted (not even an empty one).
        let none = Auth::new(auth.store().clone(), Some(&Secret::new("  ")));
        assert!(none.admin.is_none());
    }
}
